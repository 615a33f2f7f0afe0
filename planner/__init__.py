"""From FROST samples to rig poses: rig files, kinematics, reachability and move order.

Pure computation: this package imports no device or file-format I/O beyond reading YAML rig
files. Modules: ``rig`` (load_rig, Rig, AxisSpec; ``schema`` reads YAML strictly), ``alignment_file``
(ALIGNMENT.json) and ``alignment`` (its fit),
``kinematics`` (forward, inverse, Reason), ``reach`` (reachability of a whole grid, cached),
``motion`` (trapezoidal move times), ``order`` (tour search) and ``schedule`` (schedule_plan,
format_table).
"""
