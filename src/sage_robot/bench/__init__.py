"""Benchmarks (`sage bench ...`). Kept out of the test suite; numbers go to docs/benchmarks.md."""
