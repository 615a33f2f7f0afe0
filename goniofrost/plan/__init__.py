"""Making a plan: the cells selected, the sentinels and the design check added, the samples
scheduled on a rig (``make``), and PLAN.json written and read (``file``).

It sits above ``frost``, ``planner`` and ``goniofrost.rig`` and below ``capture``, which reads
PLAN.json through ``file``.
"""
