"""The project's benchmarks, by purpose: performance/ (what a step costs), validation/ (how close the
physics comes to a reference), test_power/ (how much the test suite catches). harness.py holds what
they share (flags, provenance, results); cases.py the validation cases the tests use too. Run one as
a module from the repository root: `python -m benchmarks.performance.throughput --quick`."""
