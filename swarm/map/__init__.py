"""The coverage-map model of docs/design.md section 3: pure numpy/scipy, no I/O."""
