"""From FROST samples to rig poses: rig files, kinematics, reachability and move order.

Pure computation: this package imports no device or file-format I/O beyond reading YAML rig
files. Filled by the planner issue.
"""
