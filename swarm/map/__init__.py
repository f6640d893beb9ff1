"""The coverage-map model of DESIGN.md section 3: pure numpy/scipy, no I/O."""
