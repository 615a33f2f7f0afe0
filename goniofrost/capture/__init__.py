"""The capture session: checked inputs, plan steps, the engine, journal, report, runner; the rig it
drives is ``goniofrost.rig``."""
