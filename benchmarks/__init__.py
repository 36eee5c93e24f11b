"""Benchmarks of the solvers and of the control loop (see ``benchmarks/README.md``)."""
