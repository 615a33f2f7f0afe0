"""One sample's calibrated BRDF from its finished bracket: value, uncertainty, SNR and flags.

Pure: the bracket's frames, the calibration record and the camera settings in, a
``SampleMeasurement`` out. BRDF[c] = patch rate[c] / (scale[c] cos theta_i); the relative
uncertainty combines the patch's standard error, the white reference's and the photodiode's.

Error policy: sample pixels saturated even at the shortest exposure -> SaturationError (raised by
the bracket); every channel below ``min_snr`` even with the ladder's longest exposure ->
UnderexposedError; some channels below ``min_snr`` but not all -> those channels are measurements
at their detection limit (value >= 0 with its sigma, flag ``"detection-limit"``); any channel
between ``min_snr`` and ``target_snr`` -> the flag ``"low-snr"``; read
markers more than a quarter of ``marker_tolerance_px`` from the camera model's prediction (but
within it) flag ``"markers-off"``: the rig may be misaligned (``goniofrost align``); a region the
camera model placed alone whose pixels spread more than MAX_SPREAD_RATIO times their robust spread
takes in the card around the patch: flag ``"roi-mixed"``, or MisalignedError when its SNR is
below ``min_snr``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .bracket import Bracket
from .errors import CalibrationError, MisalignedError, UnderexposedError
from .record import CalibrationRecord
from .references import unit


@dataclass
class SampleMeasurement:
    """One calibrated sample: ``rgb``, ``sigma`` (3,) BRDF and standard uncertainty in 1/sr;
    ``snr`` (3,) of the patch mean; the exposures used (s), frames taken and skipped (of the
    ladder), raw file paths, mean relative lamp level, real seconds inside the camera
    (``capture_seconds``), seconds of exposure on the session clock (``clock_seconds``: simulated
    on a simulated rig) and flags; ``roi_source`` ("markers" | "prediction") and
    ``marker_offset_px`` (the read markers' largest distance from the camera model's prediction;
    None if no marker was read)."""

    sample_id: int
    rgb: np.ndarray
    sigma: np.ndarray
    snr: np.ndarray
    exposures_s: list
    frames_taken: int
    frames_skipped: int
    raw_paths: list
    lamp_relative: float
    capture_seconds: float = 0.0
    clock_seconds: float = 0.0
    flags: list = field(default_factory=list)
    roi_source: str = ""
    marker_offset_px: float | None = None

    def to_dict(self) -> dict:
        """JSON-safe form."""
        return {"sample_id": self.sample_id, "rgb": self.rgb.tolist(), "sigma": self.sigma.tolist(),
                "snr": self.snr.tolist(), "exposures_s": self.exposures_s,
                "frames_taken": self.frames_taken, "frames_skipped": self.frames_skipped,
                "raw_paths": [str(p) for p in self.raw_paths], "lamp_relative": self.lamp_relative,
                "capture_seconds": self.capture_seconds, "clock_seconds": self.clock_seconds, "flags": self.flags,
                "roi_source": self.roi_source, "marker_offset_px": self.marker_offset_px}


def check_record(record: CalibrationRecord | None, ladder: list) -> None:
    """Refuse to measure without a calibration, or with ladder exposures it has no dark frame for."""
    if record is None:
        raise CalibrationError("measure() before calibrate(): no dark, flat or white reference")
    missing = [t for t in ladder if not any(abs(t - r) <= 1e-9 * r for r in record.exposures_s)]
    if missing:
        raise CalibrationError(f"exposures {missing} s have no dark frame in the calibration (ladder "
                               f"{record.exposures_s} s): calibrate again with this ladder")


def light_direction(w_i, sample_id: int) -> np.ndarray:
    """The unit light direction (3,) of a sample; CalibrationError when it is below the sample plane."""
    w_i = unit(w_i, f"sample {sample_id} w_i")
    if w_i[2] <= 0.0:
        raise CalibrationError(f"sample {sample_id}: light below the sample plane (w_i z = {w_i[2]:.3f})")
    return w_i


def sample_measurement(sample_id: int, bracket: Bracket, w_i: np.ndarray, capture_seconds: float = 0.0,
                       clock_seconds: float = 0.0) -> SampleMeasurement:
    """Calibrate a finished bracket at unit light direction ``w_i`` (3,) into a SampleMeasurement.

    A channel below ``min_snr`` while another channel reaches it (a strongly coloured material:
    the blue of an orange paint at grazing light) is a measurement at its detection limit: its
    value is clipped at 0 (a BRDF is >= 0, and the reconstruction takes no negative value), its
    sigma is the patch's standard error, and the flag ``"detection-limit"`` says so; the
    reconstruction's log map weighs it by that sigma.
    """
    mean, se = bracket.stats()
    rec, settings = bracket.record, bracket.settings
    to_brdf = 1.0 / (rec.scale * w_i[2])
    rgb = np.maximum(mean, 0.0) * to_brdf
    # the patch's standard error in absolute terms (a value near 0 keeps its uncertainty), the
    # white reference's and the photodiode's relative to the value
    rel_sys = np.sqrt((rec.scale_sigma / rec.scale) ** 2 + settings["photodiode_rel_sigma"] ** 2)
    sigma = np.sqrt((se * to_brdf) ** 2 + (rgb * rel_sys) ** 2)
    snr = mean / se
    flags = _snr_flags(snr, bracket) + _marker_flags(bracket)
    taken = len(bracket.frames)
    return SampleMeasurement(sample_id, rgb, sigma, snr, bracket.exposures_s, taken,
                             len(bracket.ladder) - taken, list(bracket.paths), bracket.lamp_relative,
                             capture_seconds, clock_seconds, flags, bracket.roi_source_, bracket.marker_offset_px_)


MARKERS_OFF_FRACTION = 0.25   # of marker_tolerance_px: beyond it a sample is flagged "markers-off"


def _marker_flags(bracket: Bracket) -> list:
    offset = bracket.marker_offset_px_
    limit = MARKERS_OFF_FRACTION * bracket.settings["marker_tolerance_px"]
    return ["markers-off"] if offset is not None and offset > limit else []


# A region whose pixels spread this many times their robust spread is not one material: it
# straddles the patch's edge (a uniform patch with shot and read noise stays near 1).
MAX_SPREAD_RATIO = 3.0


def _snr_flags(snr: np.ndarray, bracket: Bracket) -> list:
    settings = bracket.settings
    snr = np.nan_to_num(np.asarray(snr, dtype=float), nan=0.0)
    low, best = float(np.min(snr)), float(np.max(snr))
    # a region placed by the camera model alone may take in the card around the patch (a rig
    # that is not aligned): its pixels then spread far beyond their noise
    mixed = bracket.roi_source_ == "prediction" and bracket.spread_ratio() > MAX_SPREAD_RATIO
    if low < settings["min_snr"] and mixed:
        raise MisalignedError(
            f"{bracket.what}: the region of interest is not uniform (its pixels spread {bracket.spread_ratio():.0f} "
            f"times their median deviation): it takes in the card around the patch, so the patch is not where the "
            f"camera model puts it: the rig looks misaligned (run goniofrost align, or check the camera model)")
    if best < settings["min_snr"]:
        _too_dark(best, bracket)
    flags = ["low-snr"] if low < settings["target_snr"] else []
    flags += ["detection-limit"] if low < settings["min_snr"] else []
    return flags + (["roi-mixed"] if mixed else [])


def _too_dark(best: float, bracket: Bracket) -> None:
    """No channel reaches ``min_snr``: too dark for the ladder (UnderexposedError, whose remedy is a
    longer exposure) only when the ladder's longest exposure was taken; else the bracket stopped
    because a longer frame would saturate the patch, and the patch scatters beyond its noise."""
    longest, minimum = bracket.ladder[max(bracket.frames)], bracket.settings["min_snr"]
    if bracket.ladder_exhausted:
        raise UnderexposedError(f"{bracket.what}: SNR {best:.1f} below the minimum {minimum} with exposures up to "
                                f"{longest} s (the longest of camera.exposures_s): too dark to measure")
    raise CalibrationError(f"{bracket.what}: SNR {best:.1f} below the minimum {minimum} at {longest} s, and a longer "
                           f"exposure would saturate the patch: its pixels scatter far beyond their noise")
