"""Benchmarks of FROST against the baselines: cross-validated error and time, and stress cases.

Entry points: ``runner``; a run is described by ``config.BenchConfig``.
"""
