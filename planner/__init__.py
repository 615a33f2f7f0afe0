"""From FROST samples to rig poses: rig files, kinematics, reachability and move order.

Pure computation (no device I/O). Entry points: ``rig.load_rig``, ``kinematics.forward`` and
``inverse``, ``reach``, ``schedule.schedule_plan``.
"""
