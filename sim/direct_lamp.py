"""The lamp contract (``on``, ``off``, ``photodiode``) straight over a LampModel, without Modbus.

For calibration tests and benchmarks; a session uses ``drivers.lamp`` over the simulated Modbus
device, which reads the same LampModel through the photodiode register.
"""
from __future__ import annotations

from .lamp_model import PHOTODIODE_FULL_SCALE, LampModel


class DirectLamp:
    """Switch the modelled lamp and read its monitor photodiode (relative, 1.0 nominal)."""

    def __init__(self, model: LampModel) -> None:
        self.model = model

    def on(self) -> None:
        self.model.is_on = True

    def off(self) -> None:
        self.model.is_on = False

    def photodiode(self) -> float:
        """Relative intensity from the 16-bit photodiode counts (quantised like the register)."""
        return self.model.photodiode_counts() / PHOTODIODE_FULL_SCALE
