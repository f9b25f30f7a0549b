"""This repository's studies: one-off measurements behind benchmarks/REPORT.md and
benchmarks/STUDIES.md that `sphrender bench` does not run (the dam break on every frame, the
flicker under both readings of the jitter, the close-up crops, host time under a profiler, the
field-gradient kernels' shaders). Not installed; benchmark scripts import them through
`benchmarks/repo_path.py`, tests through tests/conftest.py."""
