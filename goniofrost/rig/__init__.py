"""The rig: its file loaded and checked, its devices opened (real, or simulated in ``simulated``, as
the caller chooses), its lock, ``rig check``, the device contract and log, and the one stop path.

It imports nothing of goniofrost but the core; ``goniofrost.capture`` and the commands build on it.
"""
