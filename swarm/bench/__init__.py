"""Benchmarks that print their figures (``swarm bench ...``)."""
