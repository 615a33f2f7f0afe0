"""One sample's calibrated BRDF from its finished bracket: value, uncertainty, SNR and flags.

``sample_measurement`` returns a ``SampleMeasurement`` (BRDF[c] = patch rate[c] / (scale[c]
cos theta_i)) or a ``NotMeasured`` record (saturated, or below the detection limit). Flags:
``detection-limit``, ``low-snr``, ``markers-off``, ``roi-mixed``. The error policy:
docs/explanations/camera.md.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from .bracket import Bracket
from .errors import CalibrationError, MisalignedError
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


class NotMeasuredReason(str, enum.Enum):
    """Why a sample has no measured value (``NotMeasured.reason``; journals store the value)."""

    BELOW_DETECTION_LIMIT = "below-detection-limit"   # no channel reached min_snr at the ladder's longest exposure
    SATURATED = "saturated"                           # patch pixels saturated at the ladder's shortest exposure

    def __str__(self) -> str:
        return self.value


# The limits of a channel not measured: its patch mean (>= 0) plus (too dark) or minus (saturated,
# from the clipped pixels) this many standard errors, a one-sided bound at about 99.9 % for
# Gaussian noise ("darker than X" and "brighter than Y" are information).
LIMIT_SIGMAS = 3.0


@dataclass
class NotMeasured:
    """A sample the rig could not measure, recorded instead of a value.

    ``reason`` a NotMeasuredReason; ``snr`` (3,) the patch mean's SNR reached per channel (0 where
    none could be computed); ``min_snr`` the rig's minimum; ``longest_exposure_s`` the longest
    exposure taken (the ladder's longest when too dark); ``lower_limit``, ``upper_limit`` (3,) BRDF
    in 1/sr the channel lies between: too dark, 0 and the patch mean + LIMIT_SIGMAS standard
    errors; saturated, the clipped patch mean - LIMIT_SIGMAS standard errors (>= 0) and
    infinity; the frames as in SampleMeasurement.
    """

    sample_id: int
    reason: NotMeasuredReason
    snr: np.ndarray
    min_snr: float
    longest_exposure_s: float
    upper_limit: np.ndarray
    lower_limit: np.ndarray
    exposures_s: list
    frames_taken: int
    frames_skipped: int
    raw_paths: list
    lamp_relative: float
    capture_seconds: float = 0.0
    clock_seconds: float = 0.0

    @property
    def best_snr(self) -> float:
        """The highest SNR over the channels."""
        return float(np.max(self.snr))

    def text(self) -> str:
        """One line for people (readers use the fields)."""
        return (f"sample {self.sample_id}: not measured ({self.reason}): "
                f"{why_not_measured(self.reason, self.snr, self.min_snr, self.exposures_s, self.lower_limit, self.upper_limit)}")


def why_not_measured(reason, snr, min_snr: float, exposures_s, lower_limit, upper_limit) -> str:
    """Why a sample was not measured and the bounds of its BRDF, in words (the one phrase the record,
    the journal's event and the session summary share); the arguments are a NotMeasured's fields."""
    if str(reason) == NotMeasuredReason.SATURATED.value:
        return (f"patch pixels saturate even at the shortest exposure {min(exposures_s):g} s; BRDF above "
                f"{_triple_text(lower_limit)} 1/sr (R/G/B)")
    return (f"SNR {max(snr):.1f} below the minimum {min_snr:g} with exposures up to {max(exposures_s):g} s; "
            f"BRDF below {_triple_text(upper_limit)} 1/sr (R/G/B)")


def remedy(reason) -> str:
    """What an operator can change to measure a sample not measured for ``reason``."""
    if str(reason) == NotMeasuredReason.SATURATED.value:
        return "add shorter exposures to camera.exposures_s in the rig file (or dim the lamp)"
    return "add longer exposures to camera.exposures_s in the rig file (or brighten the lamp)"


def _triple_text(values) -> str:
    return "/".join(f"{v:.3g}" for v in values)


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
                       clock_seconds: float = 0.0) -> SampleMeasurement | NotMeasured:
    """Calibrate a finished bracket at unit light direction ``w_i`` (3,) into a SampleMeasurement,
    or a NotMeasured record when no channel reaches ``min_snr`` with the ladder's longest exposure.

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
    missing = _saturated(sample_id, snr, to_brdf, bracket) or _too_dark(sample_id, snr, mean, se, to_brdf, bracket)
    if missing is not None:
        return NotMeasured(**missing, **_frames(bracket), capture_seconds=capture_seconds, clock_seconds=clock_seconds)
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
    low = float(np.min(np.nan_to_num(np.asarray(snr, dtype=float), nan=0.0)))
    mixed = _mixed(low, bracket)
    flags = ["low-snr"] if low < settings["target_snr"] else []
    flags += ["detection-limit"] if low < settings["min_snr"] else []
    return flags + (["roi-mixed"] if mixed else [])


def _mixed(low: float, bracket: Bracket) -> bool:
    """Whether a region placed by the camera model alone takes in the card around the patch (a rig
    that is not aligned: its pixels spread far beyond their noise); MisalignedError when that
    leaves a channel below ``min_snr`` (a dark reading that says the rig, not the sample, is off)."""
    mixed = bracket.roi_source_ == "prediction" and bracket.spread_ratio() > MAX_SPREAD_RATIO
    if low < bracket.settings["min_snr"] and mixed:
        raise MisalignedError(
            f"{bracket.what}: the region of interest is not uniform (its pixels spread {bracket.spread_ratio():.0f} "
            f"times their median deviation): it takes in the card around the patch, so the patch is not where the "
            f"camera model puts it: the rig looks misaligned (run goniofrost align, or check the camera model)")
    return mixed


def _too_dark(sample_id: int, snr: np.ndarray, mean: np.ndarray, se: np.ndarray, to_brdf: np.ndarray,
              bracket: Bracket) -> dict | None:
    """None when a channel reaches ``min_snr``. Else, when the ladder's longest exposure was taken,
    the fields of a NotMeasured record (below the detection limit: too dark for this rig); else
    CalibrationError: the bracket stopped because a longer frame would saturate the patch, and the
    patch scatters beyond its noise. A misaligned region is refused first (``_mixed``)."""
    snr = np.nan_to_num(np.asarray(snr, dtype=float), nan=0.0)
    best, minimum = float(np.max(snr)), float(bracket.settings["min_snr"])
    if best >= minimum:
        return None
    _mixed(float(np.min(snr)), bracket)
    longest = bracket.ladder[max(bracket.frames)]
    if bracket.ladder_exhausted:
        upper = (np.maximum(np.nan_to_num(mean, nan=0.0), 0.0) + LIMIT_SIGMAS * se) * to_brdf
        return {"sample_id": sample_id, "reason": NotMeasuredReason.BELOW_DETECTION_LIMIT, "snr": snr,
                "min_snr": minimum, "longest_exposure_s": float(longest), "upper_limit": upper,
                "lower_limit": np.zeros(3)}
    raise CalibrationError(f"{bracket.what}: SNR {best:.1f} below the minimum {minimum:g} at {longest} s, and a longer "
                           f"exposure would saturate the patch: its pixels scatter far beyond their noise")


def _saturated(sample_id: int, snr: np.ndarray, to_brdf: np.ndarray, bracket: Bracket) -> dict | None:
    """None unless patch pixels saturated even at the ladder's shortest exposure; then the fields
    of a NotMeasured record with the lower limit of the BRDF from the clipped pixels."""
    if not bracket.saturated_pixels_:
        return None
    clipped, se = bracket.clipped_stats()
    lower = np.maximum(np.nan_to_num(clipped - LIMIT_SIGMAS * se, nan=0.0), 0.0) * to_brdf
    return {"sample_id": sample_id, "reason": NotMeasuredReason.SATURATED,
            "snr": np.nan_to_num(np.asarray(snr, dtype=float), nan=0.0), "min_snr": float(bracket.settings["min_snr"]),
            "longest_exposure_s": float(max(bracket.exposures_s)), "upper_limit": np.full(3, np.inf),
            "lower_limit": lower}


def _frames(bracket: Bracket) -> dict:
    """The NotMeasured fields that say which frames were taken."""
    taken = len(bracket.frames)
    return {"exposures_s": bracket.exposures_s, "frames_taken": taken, "frames_skipped": len(bracket.ladder) - taken,
            "raw_paths": list(bracket.paths), "lamp_relative": bracket.lamp_relative}
