"""The live 3-D view of a mission (``swarm view``): rerun scenes fed from the Zenoh bus."""
