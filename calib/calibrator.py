"""From RAW exposure brackets to absolute BRDF values (1/sr) with a standard uncertainty.

``Calibrator.calibrate`` takes dark frames (lamp off) for every exposure of the ladder, a flat
field (the ``flat`` target), and the white reference tile (the ``white`` target, Lambertian,
known reflectance) which sets the absolute scale. ``measure`` then brackets adaptively at one
pose, finds the patch from the ArUco markers, merges the bracket to HDR and divides by the
scale, cos theta_i and the lamp level read from the monitor photodiode.

Error policy: a frame set without the expected markers -> MarkerError; sample pixels saturated
even at the shortest exposure -> SaturationError; SNR below ``min_snr`` even with the longest
useful exposure -> UnderexposedError; between ``min_snr`` and ``target_snr`` the sample is
returned with the flag ``"low-snr"``. A RAW file that cannot be read -> RawFileError (names it).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivers.rawfile import read_raw

from .config import validate_camera_section
from .errors import CalibrationError, MarkerError, SaturationError, UnderexposedError, WrongTargetError
from .hdr import BracketFrame, channel_stats, merge
from .holder import SAMPLE_MARKER_IDS, WHITE_MARKER_IDS
from .record import CalibrationRecord
from .roi import find_patch

log = logging.getLogger(__name__)
START_LEVEL = 0.5   # aim the first frame of a bracket at this fraction of the saturation level


@dataclass
class SampleMeasurement:
    """One calibrated sample: ``rgb``, ``sigma`` (3,) BRDF and standard uncertainty in 1/sr;
    ``snr`` (3,) of the patch mean; the exposures used (s), frames taken and skipped (of the
    ladder), raw file paths, mean relative lamp level, wall seconds (total, of which capture)."""

    sample_id: int
    rgb: np.ndarray
    sigma: np.ndarray
    snr: np.ndarray
    exposures_s: list
    frames_taken: int
    frames_skipped: int
    raw_paths: list
    lamp_relative: float
    seconds: float
    capture_seconds: float = 0.0
    flags: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-safe form for the session journal."""
        return {"sample_id": self.sample_id, "rgb": self.rgb.tolist(), "sigma": self.sigma.tolist(),
                "snr": self.snr.tolist(), "exposures_s": self.exposures_s,
                "frames_taken": self.frames_taken, "frames_skipped": self.frames_skipped,
                "raw_paths": [str(p) for p in self.raw_paths], "lamp_relative": self.lamp_relative,
                "seconds": self.seconds, "capture_seconds": self.capture_seconds, "flags": self.flags}


@dataclass
class _Bracket:
    frames: dict            # ladder index -> BracketFrame
    paths: list
    mask: np.ndarray | None
    channels: np.ndarray | None
    capture_seconds: float = 0.0


class Calibrator:
    """Turn camera frames into calibrated BRDF samples.

    ``camera``: a ``drivers.camera.Camera`` (connected); ``lamp``: anything with ``on()``,
    ``off()`` and ``photodiode() -> float`` (1.0 nominal); ``settings``: the rig's ``camera:``
    section. Pass ``record`` (e.g. ``CalibrationRecord.from_dict``) to reuse a calibration.
    """

    def __init__(self, camera, lamp, settings: dict, record: CalibrationRecord | None = None) -> None:
        self.camera, self.lamp = camera, lamp
        self.settings = validate_camera_section(settings, "Calibrator settings")
        self.ladder = self.settings["exposures_s"]
        self.record = record
        self._expected_rate: np.ndarray | None = None   # (3,) BRDF of the last sample, for the start exposure

    # ---- calibration -------------------------------------------------------------------
    def calibrate(self, out_dir: Path, white_pose=None) -> CalibrationRecord:
        """Dark frames, flat field and white reference; save and return the record.

        ``white_pose``: the actual (w_i, w_o) at which the white tile is held; default: the
        nominal ``white_reference`` angles of the settings (the session moves there first).
        Leaves the lamp on and the ``sample`` target mounted.
        """
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        dark = self._dark_frames(out_dir)
        flat = self._flat_field(out_dir, dark)
        self.record = CalibrationRecord(self.ladder, dark, flat, np.ones(3), np.zeros(3))
        self._white_reference(out_dir, white_pose)
        self.record.save(out_dir)
        return self.record

    def _dark_frames(self, out_dir: Path) -> np.ndarray:
        """Mean dark frame per ladder exposure, lamp off: (n, H, W) float32."""
        self.lamp.off()
        maps = []
        for i, t in enumerate(self.ladder):
            acc = None
            for k in range(self.settings["dark_frames"]):
                raw = read_raw(self.camera.capture(t, out_dir / f"dark_e{i}_{k}.dng").path)
                acc = raw.linear.astype(np.float64) if acc is None else acc + raw.linear
            maps.append((acc / self.settings["dark_frames"]).astype(np.float32))
        self.lamp.on()
        return np.stack(maps)

    def _flat_field(self, out_dir: Path, dark: np.ndarray) -> np.ndarray:
        """Gain per pixel (H, W), mean 1 per channel, from the ``flat`` target at the longest
        exposure that stays below saturation."""
        self.camera.set_target("flat")
        try:
            for i in reversed(range(len(self.ladder))):
                raw = read_raw(self.camera.capture(self.ladder[i], out_dir / f"flat_e{i}_0.dng").path)
                if np.percentile(raw.linear, 99.9) < self.settings["saturation"]:
                    break
            else:
                raise SaturationError(f"flat field: saturated even at {self.ladder[0]} s")
            acc = raw.linear - dark[i]
            for k in range(1, self.settings["flat_frames"]):
                acc += read_raw(self.camera.capture(self.ladder[i], out_dir / f"flat_e{i}_{k}.dng").path).linear - dark[i]
        finally:
            self.camera.set_target("sample")
        flat = np.empty_like(acc)
        for c in range(3):
            sel = raw.channels == c
            flat[sel] = acc[sel] / acc[sel].mean()
        if not np.all(flat > 0.05):
            raise CalibrationError(f"flat field: {int(np.sum(flat <= 0.05))} pixels see almost no light "
                                   f"(exposure {self.ladder[i]} s): is the flat target in place?")
        return flat.astype(np.float32)

    def _white_reference(self, out_dir: Path, white_pose) -> None:
        """Absolute scale per channel from the white tile: rate / (rho/pi cos theta_i)."""
        wr = self.settings["white_reference"]
        if white_pose is None:
            ti, to = np.radians(wr["theta_i_deg"]), np.radians(wr["theta_o_deg"])
            white_pose = (np.array([np.sin(ti), 0, np.cos(ti)]), np.array([-np.sin(to), 0, np.cos(to)]))
        w_i = _unit(white_pose[0], "white reference w_i")
        rho = wr["reflectance"]
        self._expected_rate = np.full(3, rho / np.pi)
        self.camera.set_target("white")
        try:
            mean, se, br = self._bracket_stats(w_i, out_dir, "white", WHITE_MARKER_IDS, "white reference")
        finally:
            self.camera.set_target("sample")
        denom = rho / np.pi * w_i[2]
        self.record.scale = mean / denom
        rel = np.hypot(se / mean, self.settings["photodiode_rel_sigma"])
        self.record.scale_sigma = self.record.scale * rel
        self.record.white = {"reflectance": rho, "w_i": w_i.tolist(), "w_o": list(map(float, white_pose[1])),
                             "exposures_s": [self.ladder[i] for i in sorted(br.frames)],
                             "snr": (mean / se).tolist()}
        self._expected_rate = None

    # ---- measurement -------------------------------------------------------------------
    def measure(self, w_i, w_o, out_dir: Path, sample_id: int) -> SampleMeasurement:
        """Capture and calibrate one sample at light/view directions (3,) in the sample frame."""
        self._check_record()
        t0 = time.perf_counter()
        w_i = _unit(w_i, f"sample {sample_id} w_i")
        if w_i[2] <= 0.0:
            raise CalibrationError(f"sample {sample_id}: light below the sample plane (w_i z = {w_i[2]:.3f})")
        what = f"sample {sample_id}"
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        mean, se, br = self._bracket_stats(w_i, Path(out_dir), f"sample_{sample_id:04d}", SAMPLE_MARKER_IDS, what)
        rec = self.record
        rgb = mean / (rec.scale * w_i[2])
        rel = np.sqrt((se / mean) ** 2 + (rec.scale_sigma / rec.scale) ** 2 + self.settings["photodiode_rel_sigma"] ** 2)
        snr = mean / se
        flags = self._check_snr(snr, what, br)
        self._expected_rate = np.maximum(rgb, 1e-6)
        lamp = float(np.mean([f.lamp_relative for f in br.frames.values()]))
        exps = [self.ladder[i] for i in sorted(br.frames)]
        return SampleMeasurement(sample_id, rgb, np.abs(rgb) * rel, snr, exps, len(br.frames),
                                 len(self.ladder) - len(br.frames), br.paths, lamp,
                                 time.perf_counter() - t0, br.capture_seconds, flags)

    def _check_record(self) -> None:
        if self.record is None:
            raise CalibrationError("measure() before calibrate(): no dark, flat or white reference")
        missing = [t for t in self.ladder if not any(abs(t - r) <= 1e-9 * r for r in self.record.exposures_s)]
        if missing:
            raise CalibrationError(f"exposures {missing} s have no dark frame in the calibration (ladder "
                                   f"{self.record.exposures_s} s): calibrate again with this ladder")

    def _check_snr(self, snr: np.ndarray, what: str, br: _Bracket) -> list:
        low = float(np.nanmin(snr)) if np.all(np.isfinite(snr)) else 0.0
        if low < self.settings["min_snr"]:
            longest = self.ladder[max(br.frames)]
            raise UnderexposedError(f"{what}: SNR {low:.1f} below the minimum {self.settings['min_snr']} "
                                    f"with exposures up to {longest} s: too dark to measure")
        return ["low-snr"] if low < self.settings["target_snr"] else []

    def _bracket_stats(self, w_i, out_dir: Path, stem: str, ids, what: str):
        """Bracket adaptively; return the patch's mean rate and standard error (3,) and the bracket."""
        br = self._bracket(w_i, out_dir, stem, ids, what)
        mean, se, _ = self._stats(br)
        if not np.all(mean > 0):
            raise UnderexposedError(f"{what}: no signal above the dark level in channel(s) "
                                    f"{[c for c, m in zip('RGB', mean) if not m > 0]}")
        return mean, se, br

    # ---- adaptive bracketing -----------------------------------------------------------
    def _bracket(self, w_i, out_dir: Path, stem: str, ids, what: str) -> _Bracket:
        """Take ladder exposures until every patch pixel has an unsaturated frame and the
        patch mean reaches the target SNR, or no further exposure can help."""
        br = _Bracket({}, [], None, None)
        i, marker_error = self._start_index(w_i), None
        while i is not None:
            self._take(br, i, out_dir, stem)
            if br.mask is None:
                try:
                    br.mask = find_patch(br.frames[i].linear, ids, self.settings["roi_margin"], what)
                except WrongTargetError:
                    raise            # another exposure will not change which card is mounted
                except MarkerError as exc:
                    log.debug("%s: markers not found at %s s: %s", what, self.ladder[i], exc)
                    marker_error = exc
            i = self._next_index(br, i, what) if br.mask is not None else self._search_index(br, i)
        if br.mask is None:
            raise MarkerError(f"{marker_error} (in all {len(br.frames)} exposures)") from marker_error
        return br

    def _start_index(self, w_i) -> int:
        """Longest exposure at which the expected patch level stays below START_LEVEL x saturation."""
        if not self.record.white:            # scale not known yet (white reference itself)
            return len(self.ladder) // 2
        brdf = self._expected_rate if self._expected_rate is not None else np.full(3, 1 / np.pi)
        rate = float(np.max(brdf * self.record.scale)) * w_i[2]
        fits = [k for k, t in enumerate(self.ladder) if rate * t <= START_LEVEL * self.settings["saturation"]]
        return fits[-1] if fits else 0

    def _take(self, br: _Bracket, i: int, out_dir: Path, stem: str) -> None:
        t = self.ladder[i]
        path = out_dir / f"{stem}_e{i}.dng"
        before = self.lamp.photodiode()
        c0 = time.perf_counter()
        frame = self.camera.capture(t, path)
        br.capture_seconds += time.perf_counter() - c0
        lamp = 0.5 * (before + self.lamp.photodiode())
        if not lamp > 0:
            raise CalibrationError(f"{path}: the monitor photodiode reads {lamp}: is the lamp on?")
        raw = read_raw(frame.path)
        sat = raw.saturated | (raw.linear >= self.settings["saturation"])
        br.frames[i] = BracketFrame(raw.linear, sat, t, self.record.dark_for(t), lamp)
        br.paths.append(frame.path)
        br.channels = raw.channels
        log.debug("%s: exposure %s s, lamp %.4f, %d saturated pixels", path, t, lamp, int(sat.sum()))

    def _search_index(self, br: _Bracket, i: int) -> int | None:
        """Markers not found yet: try the nearest untaken exposure, shorter first if this frame
        is mostly saturated, else longer first."""
        left = [k for k in range(len(self.ladder)) if k not in br.frames]
        if not left:
            return None
        bright = np.mean(br.frames[i].saturated) > 0.25
        return min(left, key=lambda k: (abs(k - i), (k > i) if bright else (k < i)))

    def _next_index(self, br: _Bracket, i: int, what: str) -> int | None:
        lo, hi = min(br.frames), max(br.frames)
        _, covered = merge(list(br.frames.values()), self.record.flat, br.mask)
        if not covered.all():
            if lo == 0:
                raise SaturationError(f"{what}: {int((~covered).sum())} of {covered.size} sample pixels "
                                      f"saturate even at the shortest exposure {self.ladder[0]} s")
            return lo - 1
        mean, se, _ = self._stats(br)
        if np.all(mean / se >= self.settings["target_snr"]) or hi + 1 >= len(self.ladder):
            return None
        level = np.median(br.frames[hi].linear[br.mask]) * self.ladder[hi + 1] / self.ladder[hi]
        return hi + 1 if level < self.settings["saturation"] else None

    def _stats(self, br: _Bracket):
        rates, _ = merge(list(br.frames.values()), self.record.flat, br.mask)
        return channel_stats(rates, br.channels[br.mask])


def _unit(v, what: str) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(-1)
    n = float(np.linalg.norm(v)) if v.size == 3 else 0.0
    if not n > 0 or not np.isfinite(n):
        raise CalibrationError(f"{what}: expected a non-zero direction vector (3,), found {v.tolist()}")
    return v / n
