"""The adaptive exposure bracket as a rule: which ladder exposure to take next, from the frames so far.

Pure: ``Bracket.add(frame)`` returns the next exposure, or None when the bracket is done. The
rule: docs/explanations/camera.md.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import (CalibrationError, MarkerError, MisalignedError, PatchTooSmallError, SaturationError,
                     WrongTargetError)
from .hdr import BracketFrame, channel_stats, merge
from .record import CalibrationRecord
from .roi import PredictedView, locate_patch

log = logging.getLogger(__name__)
START_LEVEL = 0.5   # aim the first frame of a bracket at this fraction of the saturation level


def start_index(ladder: list, settings: dict, record: CalibrationRecord, expected, w_i) -> int:
    """Ladder index of a bracket's first exposure.

    ``expected``: (3,) BRDF in 1/sr the patch probably has (the previous sample's), or None (a
    white-like 1/pi); ``w_i``: (3,) unit light direction. Without a white reference yet (the
    white reference's own bracket) the middle of the ladder.
    """
    if not record.white:
        return len(ladder) // 2
    brdf = expected if expected is not None else np.full(3, 1 / np.pi)
    rate = float(np.max(brdf * record.scale)) * w_i[2]
    fits = [k for k, t in enumerate(ladder) if rate * t <= START_LEVEL * settings["saturation"]]
    return fits[-1] if fits else 0


MAX_SATURATED_FRACTION = 0.25  # a frame more saturated than this is too bright to read
MIN_BRIGHT_END = 0.02          # a frame whose 99th percentile is below this (of full scale) is too dark


def markers_exposed(frame: BracketFrame) -> bool:
    """Whether a frame is exposed well enough to read markers: at most a quarter saturated, and
    its bright end (99th percentile) at least 2 % of full scale (far above the read noise)."""
    return bool(np.mean(frame.saturated) <= MAX_SATURATED_FRACTION
                and np.percentile(frame.linear, 99) >= MIN_BRIGHT_END)


@dataclass
class Bracket:
    """The frames of one bracket so far, and the rule that asks for the next exposure.

    ``ladder`` (n,) exposures in s; ``settings`` the validated camera section; ``record`` the
    calibration (dark maps, flat field; scale once the white reference is known); ``ids`` the
    marker ids of the mounted target; ``what`` names the sample in errors; ``view`` where the
    camera model puts the patch and the markers at this pose (``calib.roi.expected_view``; None:
    the markers alone). Learned as frames are added: ``frames`` (ladder index -> BracketFrame),
    ``paths``, ``mask_`` (H, W) bool patch, ``channels_`` (H, W) Bayer channel per pixel,
    ``roi_source_`` ("markers" | "prediction") and ``marker_offset_px_`` (read markers' largest
    distance from the prediction; None if none was read). ``record_saturation``: when even the
    shortest exposure saturates patch pixels, end the bracket and count them in ``saturated_pixels_``
    (a plan sample: recorded as not measured, the capture goes on) instead of raising
    SaturationError (a reference, which the session cannot do without).
    """

    ladder: list
    settings: dict
    record: CalibrationRecord
    ids: tuple
    what: str
    frames: dict = field(default_factory=dict)
    paths: list = field(default_factory=list)
    mask_: np.ndarray | None = None
    channels_: np.ndarray | None = None
    marker_error_: MarkerError | None = None
    view: PredictedView | None = None
    roi_source_: str = ""
    marker_offset_px_: float | None = None
    fallback_: np.ndarray | None = None
    record_saturation: bool = False
    saturated_pixels_: int = 0

    def add(self, i: int, raw, lamp_relative: float, path: Path, exposure_s: float | None = None) -> int | None:
        """Add the frame of ladder exposure ``i`` (``raw``: a drivers.rawfile.RawImage; lamp level
        relative to nominal during it; ``exposure_s``: the exposure the camera reports it took,
        default the rung's); return the next ladder index to take, or None when done."""
        if not lamp_relative > 0:
            raise CalibrationError(f"{path}: the monitor photodiode reads {lamp_relative}: is the lamp on?")
        t = self.ladder[i] if exposure_s is None else float(exposure_s)
        saturated = raw.clipped(self.settings["saturation"])
        self.frames[i] = BracketFrame(raw.linear, saturated, t, self.record.dark_for(self.ladder[i]), lamp_relative)
        self.paths.append(path)
        self.channels_ = raw.channels
        log.debug("%s: exposure %s s, lamp %.4f, %d saturated pixels", path, t, lamp_relative, int(saturated.sum()))
        if self.mask_ is None:
            self._find_patch(i)
        if self.mask_ is None:
            following = self._search_index(i)
            if following is not None or self.fallback_ is None:
                return following
            # every exposure tried and no marker read: the camera model alone places the patch
            self.mask_, self.roi_source_ = self.fallback_, "prediction"
        return self._next_index(i)

    def stats(self) -> tuple[np.ndarray, np.ndarray]:
        """The patch's mean rate and its standard error, each (3,), once the bracket is done.

        MarkerError when no frame showed the markers. A mean may be <= 0 (a channel with no signal
        above the dark level): ``calib.measurement`` records it as a detection limit.
        """
        if self.mask_ is None:
            raise MarkerError(f"{self.marker_error_} (in all {len(self.frames)} exposures)") from self.marker_error_
        return self._stats()

    @property
    def exposures_s(self) -> list:
        """The exposures taken, shortest first (s): as the camera reported them."""
        return [self.frames[i].exposure_s for i in sorted(self.frames)]

    @property
    def lamp_relative(self) -> float:
        """Mean relative lamp level over the frames taken."""
        return float(np.mean([f.lamp_relative for f in self.frames.values()]))

    def _find_patch(self, i: int) -> None:
        s = self.settings
        try:
            self.mask_, self.roi_source_, self.marker_offset_px_ = locate_patch(
                self.frames[i].linear, self.ids, s["roi_margin"], self.what, self.view,
                s["marker_tolerance_px"], self.channels_, s["min_roi_pixels"], whole_frame=markers_exposed(self.frames[i]))
        except (WrongTargetError, MisalignedError, PatchTooSmallError):
            raise            # another exposure will not change the card, the rig or the view
        except MarkerError as exc:
            log.debug("%s: markers not found at %s s: %s", self.what, self.ladder[i], exc)
            self.marker_error_ = exc
            return
        if self.roi_source_ == "prediction" and self.view.readable and not markers_exposed(self.frames[i]):
            # markers that should be readable, in a frame too dark or too bright to read them:
            # another exposure may show them (the prediction stays as the last resort)
            self.fallback_, self.mask_ = self.mask_, None
            self.marker_error_ = MarkerError(f"{self.what}: markers {list(self.view.readable)} predicted readable, "
                                             f"none read at {self.ladder[i]} s")

    def _search_index(self, i: int) -> int | None:
        """Markers not found yet: the nearest untaken exposure, shorter first if this frame is
        mostly saturated, else longer first."""
        left = [k for k in range(len(self.ladder)) if k not in self.frames]
        if not left:
            return None
        bright = np.mean(self.frames[i].saturated) > 0.25
        return min(left, key=lambda k: (abs(k - i), (k > i) if bright else (k < i)))

    def _next_index(self, i: int) -> int | None:
        lo, hi = min(self.frames), max(self.frames)
        _, covered = merge(list(self.frames.values()), self.record.flat, self.mask_)
        if not covered.all():
            if lo == 0 and self.record_saturation:
                self.saturated_pixels_ = int((~covered).sum())
                return None
            if lo == 0:
                raise SaturationError(f"{self.what}: {int((~covered).sum())} of {covered.size} sample pixels "
                                      f"saturate even at the shortest exposure {self.ladder[0]} s")
            return lo - 1
        return hi + 1 if self.lagging(hi) else None

    def lagging(self, hi: int) -> list:
        """The channels (0..2) that are below ``target_snr`` and that the next longer ladder exposure
        than index ``hi`` would still expose (the median of the channel's own pixels predicted below
        saturation): each channel is exposed as long as it needs, whatever a brighter channel does
        (its saturated pixels are left out of the merge). Empty at the end of the ladder."""
        if hi + 1 >= len(self.ladder):
            return []
        mean, se = self._stats()
        frame, channels = self.frames[hi].linear[self.mask_], self.channels_[self.mask_]
        gain = self.ladder[hi + 1] / self.ladder[hi]
        # a channel whose value is consistent with zero has an SNR near 0 (NaN when 0 / 0):
        # it is lagging until the ladder ends, then its uncertainty is its detection limit
        below = ~(np.nan_to_num(mean / se, nan=0.0) >= self.settings["target_snr"])
        return [c for c in range(3) if below[c] and
                np.median(frame[channels == c]) * gain < self.settings["saturation"]]

    @property
    def ladder_exhausted(self) -> bool:
        """Whether the longest exposure taken is the ladder's longest (the rig has no longer one)."""
        return max(self.frames) == len(self.ladder) - 1

    def _stats(self) -> tuple[np.ndarray, np.ndarray]:
        rates, _ = merge(list(self.frames.values()), self.record.flat, self.mask_)
        mean, se, _ = channel_stats(rates, self.channels_[self.mask_])
        return mean, se

    def clipped_stats(self) -> tuple[np.ndarray, np.ndarray]:
        """The patch's mean rate and its standard error, each (3,), from the shortest exposure taken
        with its saturated pixels at their clipped values: a mean no higher than the true one."""
        frame = self.frames[min(self.frames)]
        clipped = BracketFrame(frame.linear, np.zeros_like(frame.saturated), frame.exposure_s, frame.dark,
                               frame.lamp_relative)
        rates, _ = merge([clipped], self.record.flat, self.mask_)
        mean, se, _ = channel_stats(rates, self.channels_[self.mask_])
        return mean, se

    def spread_ratio(self) -> float:
        """Largest, over the colour channels, ratio of the region's pixel standard deviation to its
        robust spread (1.4826 x median absolute deviation): about 1 for a uniform patch, far more
        when the region takes in pixels of the card around the patch."""
        rates, _ = merge(list(self.frames.values()), self.record.flat, self.mask_)
        channels, worst = self.channels_[self.mask_], 0.0
        for c in range(3):
            v = rates[(channels == c) & np.isfinite(rates)]
            if v.size >= 8:
                robust = 1.4826 * np.median(np.abs(v - np.median(v)))
                worst = max(worst, float(np.std(v) / robust) if robust > 0 else float("inf"))
        return worst
