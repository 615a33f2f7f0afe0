"""The calibration record: dark maps, flat field and the absolute scale.

Arrays in ``calibration.npz``; ``to_dict`` gives a JSON-safe summary with the file's SHA-256 and
``from_dict`` refuses a file that changed.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import CalibrationError

RECORD_VERSION = 1


@dataclass
class CalibrationRecord:
    """Calibration state.

    ``exposures_s`` (n,) ladder; ``dark`` (n, H, W) float32 mean dark frame per exposure (linear
    units); ``flat`` (H, W) float32 gain, mean 1 per Bayer channel; ``scale`` (3,) rate per
    (BRDF 1/sr x cos theta_i), from the white tile; ``scale_sigma`` (3,) its standard
    uncertainty; ``white`` the white-reference facts (reflectance, directions, lamp level).
    """

    exposures_s: list
    dark: np.ndarray
    flat: np.ndarray
    scale: np.ndarray
    scale_sigma: np.ndarray
    white: dict = field(default_factory=dict)
    path: Path | None = None
    sha256: str = ""

    def dark_for(self, exposure_s: float) -> np.ndarray:
        """The dark map (H, W) of a ladder exposure."""
        for i, t in enumerate(self.exposures_s):
            if abs(t - exposure_s) <= 1e-9 * max(t, 1e-12):
                return self.dark[i]
        raise CalibrationError(f"no dark frame for exposure {exposure_s} s; calibrated ladder: {self.exposures_s}")

    def save(self, out_dir: Path) -> Path:
        """Write the arrays to OUT_DIR/calibration.npz atomically; remember path and hash."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / "calibration.npz"
        tmp = out_dir / f".calibration.npz.tmp{os.getpid()}"
        try:
            with open(tmp, "wb") as fh:
                np.savez(fh, dark=self.dark, flat=self.flat)
            os.replace(tmp, path)
        except BaseException:  # a full disk leaves no partial file behind
            tmp.unlink(missing_ok=True)
            raise
        self.path, self.sha256 = path, _sha256(path)
        return path

    def to_dict(self) -> dict:
        """JSON-safe summary; needs ``save`` first (the arrays are referenced by path + hash)."""
        if self.path is None:
            raise CalibrationError("calibration record: save() it before to_dict()")
        return {"version": RECORD_VERSION, "arrays": str(self.path), "sha256": self.sha256,
                "exposures_s": list(map(float, self.exposures_s)), "scale": self.scale.tolist(),
                "scale_sigma": self.scale_sigma.tolist(), "white": self.white}

    @classmethod
    def from_dict(cls, d: dict) -> "CalibrationRecord":
        """Rebuild a record from ``to_dict`` output; CalibrationError if the arrays changed."""
        if not isinstance(d, dict) or d.get("version") != RECORD_VERSION:
            raise CalibrationError(f"calibration record: expected version {RECORD_VERSION}, "
                                   f"found {d.get('version') if isinstance(d, dict) else d!r}")
        path = Path(d["arrays"])
        if not path.is_file():
            raise CalibrationError(f"{path}: calibration arrays not found")
        if _sha256(path) != d["sha256"]:
            raise CalibrationError(f"{path}: calibration arrays changed since the record was "
                                   f"written (SHA-256 differs)")
        with np.load(path) as z:
            dark, flat = z["dark"], z["flat"]
        return cls(list(d["exposures_s"]), dark, flat, np.asarray(d["scale"], float),
                   np.asarray(d["scale_sigma"], float), dict(d["white"]), path, d["sha256"])


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
