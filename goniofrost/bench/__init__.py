"""Benchmarks of FROST against the baselines: cross-validated error and time, and stress cases.

Modules: ``config`` (what a run does, fold splits, seeds), ``data`` (tabulation cache),
``evaluate`` (the work of one fold), ``executors`` (local processes or Dask), ``results``
(files and statistics), ``plots``, ``stress``, ``runner`` (the two entry points).
"""
