"""The capture session: checked inputs, plan steps, the engine and its hardware, journal, report, runner."""
