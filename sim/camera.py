"""The simulated camera: renders the sample holder from the current pose and writes DNG files.

Geometry from the rig file's camera model (the one the planner and calibration use); radiometry
far-field. The sensor is Bayer RGGB with shot, read and dark noise, PRNU, vignetting, black and
14-bit white levels. The model: docs/explanations/simulated-rig.md.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np

from calib.holder import DEFAULT_LAYOUT, SAMPLE_MARKER_IDS, WHITE_MARKER_IDS, HolderLayout
from drivers.camera import Camera, CameraError, RawFrame
from goniofrost.core.camera_model import CameraModel
from goniofrost.core.config_check import Key, check_section, is_number as _num
from goniofrost.core.errors import ConfigError

from .clock import SimClock
from .dng import write_dng
from .lamp_model import LampModel

WHITE_TILE_REFLECTANCE = 0.95   # the Lambertian white reference tile (and the flat diffuser)
PAPER_REFLECTANCE = 0.85        # holder card around the markers
INK_REFLECTANCE = 0.04          # printed marker black
BACKGROUND_REFLECTANCE = 0.01   # black velvet beyond the card
SUPERSAMPLE = 3                 # sub-pixel samples per axis: smooth marker and patch edges

# key: Key(check, expected, default: REQUIRED when none is given)
_SIM_CAMERA_KEYS = {
    "black_level": Key(lambda v: isinstance(v, int) and 0 <= v < 65535, "an integer in [0, 65535)"),
    "white_level": Key(lambda v: isinstance(v, int) and 0 < v <= 65535, "an integer in (0, 65535]"),
    "read_noise_e": Key(lambda v: _num(v) and v >= 0, "a number >= 0 (electrons)"),
    "full_well_e": Key(lambda v: _num(v) and v > 0, "a number > 0 (electrons)"),
    "dark_current_e_s": Key(lambda v: _num(v) and v >= 0, "a number >= 0 (electrons per second)"),
    "vignetting": Key(lambda v: _num(v) and 0 <= v < 1, "a number in [0, 1) (fractional fall-off at the corners)"),
    "signal_e_s": Key(lambda v: _num(v) and v > 0, "a number > 0 (electrons/s, green, white BRDF 1/pi at normal incidence)", 2.0e5),
    "channel_gain": Key(lambda v: isinstance(v, list) and len(v) == 3 and all(_num(x) and x > 0 for x in v),
                     "a list of three numbers > 0 (R, G, B response)", [0.6, 1.0, 0.75]),
    "prnu": Key(lambda v: _num(v) and 0 <= v < 0.2, "a number in [0, 0.2) (pixel gain spread, 1 sigma)", 0.01),
    "noise": Key(lambda v: isinstance(v, bool), "true or false", True),
}


def validate_sim_camera_section(section, source, keypath: str = "sim.camera") -> dict:
    """Check the rig file's ``sim.camera`` mapping; return it with defaults filled in.

    Raises ConfigError naming ``source`` and the key for a missing, unknown or bad value.
    """
    out = check_section(section, _SIM_CAMERA_KEYS, source, keypath)
    if out["white_level"] <= out["black_level"]:
        raise ConfigError(source, f"{keypath}.white_level", f"above black_level {out['black_level']}",
                          out["white_level"])
    return out


@lru_cache(maxsize=8)
def _card_texture(lay: HolderLayout, ids: tuple, texel_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Card reflectance (N, N) float32 with the patch left at 0, and the patch mask (N, N).

    Cached: every camera of a process draws the same card (read-only arrays).
    """
    import cv2

    aruco = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    n = int(round(2 * lay.half_size / texel_mm))
    centres = -lay.half_size + (np.arange(n) + 0.5) * texel_mm
    x, y = np.meshgrid(centres, -centres)          # row 0 is the top (+y) edge
    card = np.full(x.shape, PAPER_REFLECTANCE, dtype=np.float32)
    patch = ((np.abs(x) <= lay.patch_half) & (np.abs(y) <= lay.patch_half)).astype(np.float32)
    card[patch > 0] = 0.0
    cell = lay.marker_size / 6
    for mid, corners in lay.marker_corners(ids).items():
        bits = cv2.aruco.generateImageMarker(aruco, mid, 6, borderBits=1) > 127
        x0, y0 = corners[0]
        i, j = np.floor((y0 - y) / cell).astype(int), np.floor((x - x0) / cell).astype(int)
        inside = (i >= 0) & (i < 6) & (j >= 0) & (j < 6)
        card[inside] = np.where(bits[i[inside], j[inside]], PAPER_REFLECTANCE, INK_REFLECTANCE)
    card.flags.writeable = patch.flags.writeable = False
    return card, patch


# The material the camera sees: brdf(w_i, w_o) -> (3,) float64 RGB in 1/sr for unit directions (3,)
# in the sample frame. The simulator is handed it (e.g. by goniofrost.datasets.material_brdf), so it
# never needs to know where materials come from.
BrdfFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]


class HolderRenderer:
    """Pinhole views of the holder card: its reflectance and the patch's coverage per pixel.

    The card is drawn once as a texture (TEXEL_MM per texel) in the plane; a view warps it through
    the plane-to-image homography of the camera model at SUPERSAMPLE x resolution (then through
    the lens distortion, if any) and averages down, so marker and patch edges are anti-aliased.
    """

    TEXEL_MM = 0.1

    def __init__(self, model: CameraModel, arm_side: float = 1.0, layout: HolderLayout = DEFAULT_LAYOUT) -> None:
        self.model, self.arm_side, self.layout = model, float(arm_side), layout
        self.width, self.height = model.width, model.height
        self._textures = {ids: _card_texture(layout, ids, self.TEXEL_MM)
                          for ids in (SAMPLE_MARKER_IDS, WHITE_MARKER_IDS)}
        self._lens_maps = None   # distortion remap at supersampled resolution, built on first use
        self._last = None        # (key, view): the frames of one bracket share their pose

    def view(self, w_i: np.ndarray, w_o: np.ndarray, marker_ids) -> tuple[np.ndarray, np.ndarray]:
        """Mean card reflectance and patch coverage per pixel, each (H, W) float32 read-only, of
        the pose (w_i, w_o) (unit, sample frame, w_o z > 0); beyond the card lies the background.
        The last pose's view is kept: a bracket's exposures at one pose render it once."""
        key = (np.asarray(w_i, dtype=np.float64).tobytes(), np.asarray(w_o, dtype=np.float64).tobytes(),
               tuple(marker_ids))
        if self._last is None or self._last[0] != key:
            card, cover = self._render(w_i, w_o, marker_ids)
            card.flags.writeable = cover.flags.writeable = False
            self._last = (key, (card, cover))
        return self._last[1]

    def _render(self, w_i: np.ndarray, w_o: np.ndarray, marker_ids) -> tuple[np.ndarray, np.ndarray]:
        """``view`` computed: the card warped through the pose's homography (no memo)."""
        import cv2

        n, lay, tau = SUPERSAMPLE, self.layout, self.TEXEL_MM
        # texel (u, v) -> plane (x, y) mm -> undistorted pixel -> sub-pixel (OpenCV: centres on integers)
        plane = np.array([[tau, 0, -lay.half_size + 0.5 * tau], [0, -tau, lay.half_size - 0.5 * tau], [0, 0, 1]])
        sub = np.array([[n, 0, (n - 1) / 2], [0, n, (n - 1) / 2], [0, 0, 1]])
        m = sub @ self.model.plane_homography(w_i, w_o, self.arm_side) @ plane
        x0, y0, x1, y1 = self._card_box(w_i, w_o)
        shift = np.array([[1, 0, -x0 * n], [0, 1, -y0 * n], [0, 0, 1]])
        size = ((x1 - x0) * n, (y1 - y0) * n)
        card, patch = self._textures[tuple(marker_ids)]
        out = []
        for tex, border in ((card, BACKGROUND_REFLECTANCE), (patch, 0.0)):
            full = np.full((self.height, self.width), border, dtype=np.float32)
            if size[0] > 0 and size[1] > 0:
                img = cv2.warpPerspective(tex, shift @ m, size, flags=cv2.INTER_LINEAR,
                                          borderMode=cv2.BORDER_CONSTANT, borderValue=border)
                if any(self.model.distortion):
                    img = cv2.remap(img, *self._lens(), cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                    borderValue=border)
                full[y0:y1, x0:x1] = img.reshape(y1 - y0, n, x1 - x0, n).mean(axis=(1, 3))
            out.append(full)
        return out[0], out[1]

    def _card_box(self, w_i, w_o) -> tuple[int, int, int, int]:
        """Pixel box (x0, y0, x1, y1) holding the card (only it is warped: rendering time follows
        the card's size, not the frame's); the whole frame when the lens distorts."""
        if any(self.model.distortion):
            return 0, 0, self.width, self.height
        h = self.layout.half_size
        px = self.model.project_plane([[-h, -h], [h, -h], [h, h], [-h, h]], w_i, w_o, self.arm_side)
        lo = np.floor(np.nanmin(px, axis=0)).astype(int) - 2
        hi = np.ceil(np.nanmax(px, axis=0)).astype(int) + 3
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        return x0, y0, max(min(hi[0], self.width), x0), max(min(hi[1], self.height), y0)

    def _lens(self) -> tuple[np.ndarray, np.ndarray]:
        """Remap tables (sub-pixel grids, float32): for each sub-pixel of the distorted image,
        where it lies in the undistorted one."""
        import cv2

        if self._lens_maps is None:
            n, mdl = SUPERSAMPLE, self.model
            rows, cols = np.mgrid[0:self.height * n, 0:self.width * n].astype(np.float64)
            pix = np.stack([(cols + 0.5) / n - 0.5, (rows + 0.5) / n - 0.5], -1).reshape(-1, 1, 2)
            ideal = cv2.undistortPoints(pix, mdl.K, mdl.dist, R=None, P=mdl.K,
                                        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9))
            ideal = ideal.reshape(rows.shape + (2,)) * n + (n - 1) / 2
            self._lens_maps = (ideal[..., 0].astype(np.float32), ideal[..., 1].astype(np.float32))
        return self._lens_maps


class SimCamera(Camera):
    """A simulated camera looking at the sample holder; implements ``drivers.camera.Camera``.

    ``material`` is the material's name (``SPEC:NAME``, written into each DNG's metadata) and
    ``brdf`` its ground truth (``BrdfFunction``; None: only the white and flat targets can be
    shown); ``pose_source()`` returns the actual unit vectors (w_i, w_o), each (3,), in the sample
    frame; ``params`` is the rig's ``sim.camera`` section (the sensor); ``model`` the rig's camera
    model (image size, optics, mount) and ``arm_side`` the side of the light the arm works on
    (``planner.kinematics.arm_side``); ``seed`` fixes the pixel-response pattern and, with each
    frame's nominal start time, its noise.
    Exposure time passes on ``clock``.
    """

    def __init__(self, material: str | None, brdf: BrdfFunction | None,
                 pose_source: Callable[[], tuple[np.ndarray, np.ndarray]], lamp: LampModel, clock: SimClock,
                 params: dict, seed: int = 0, *, model: CameraModel, arm_side: float = 1.0) -> None:
        self.material, self.brdf, self.pose_source, self.lamp, self.clock = material, brdf, pose_source, lamp, clock
        self.params = validate_sim_camera_section(params, "SimCamera params", "sim.camera")
        self.model, self.arm_side = model, float(arm_side)
        self.seed = int(seed)
        self.target = "sample"
        self._connected = False

    def connect(self) -> None:
        """Build the renderer and the fixed pixel pattern."""
        p = self.params
        self._renderer = HolderRenderer(self.model, self.arm_side)
        pattern = np.random.default_rng(self.seed)  # the sensor's fixed pixel-response pattern
        shape = (self.model.height, self.model.width)
        self._channels = np.zeros(shape, dtype=np.uint8)      # RGGB
        self._channels[0::2, 1::2] = 1
        self._channels[1::2, 0::2] = 1
        self._channels[1::2, 1::2] = 2
        rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
        r2 = ((cols + 0.5 - shape[1] / 2) ** 2 + (rows + 0.5 - shape[0] / 2) ** 2) / (
            (shape[0] / 2) ** 2 + (shape[1] / 2) ** 2)
        self._gain = (1.0 - p["vignetting"] * r2) * (1.0 + p["prnu"] * pattern.standard_normal(shape))
        self._connected = True

    def close(self) -> None:
        self._connected = False

    def ground_truth(self, w_i, w_o) -> np.ndarray:
        """The material's BRDF (R, G, B) in 1/sr at directions (3,)."""
        if self.brdf is None:
            raise CameraError("simulated camera: no material given, so the sample card cannot be shown")
        return np.asarray(self.brdf(np.asarray(w_i, float), np.asarray(w_o, float)), dtype=np.float64).reshape(3)

    def capture(self, exposure_s: float, path: Path) -> RawFrame:
        """Render, expose, digitise and write one DNG at ``path``; returns once the exposure's
        (simulated) time has passed, the rendering and the file written within it."""
        mosaic, meta, ends = self._expose(exposure_s)
        write_dng(Path(path), mosaic, self.params["black_level"], self.params["white_level"], meta)
        self.clock.wait_until(ends)
        return RawFrame(Path(path), float(exposure_s), meta)

    def expose(self, exposure_s: float) -> tuple[np.ndarray, dict]:
        """Render the current pose and target, expose for ``exposure_s`` (the clock advances) and
        digitise: the RGGB mosaic (H, W) uint16 in DN and the frame's metadata."""
        mosaic, meta, ends = self._expose(exposure_s)
        self.clock.wait_until(ends)
        return mosaic, meta

    def _expose(self, exposure_s: float) -> tuple[np.ndarray, dict, float]:
        """``expose`` without its wait: the mosaic, the metadata and the wall-clock instant
        (``time.monotonic``) the exposure ends, to be waited for (``SimClock.wait_until``)."""
        if not self._connected:
            raise CameraError("simulated camera: capture before connect()")
        if not (_num(exposure_s) and exposure_s > 0):
            raise CameraError(f"simulated camera: exposure must be > 0 s, found {exposure_s!r}")
        w_i, w_o = (np.asarray(v, dtype=np.float64) for v in self.pose_source())
        t0 = self.clock.nominal_time()  # not the wall clock: reruns give the same frames
        ends = self.clock.start_sleep(exposure_s)   # the frame is computed while it is exposed
        lamp = 0.5 * (self.lamp.relative_intensity(t0) + self.lamp.relative_intensity(t0 + exposure_s))
        radiance = self._radiance(w_i, w_o) * lamp
        mosaic = self._digitise(radiance, exposure_s, self._frame_noise(t0))
        meta = {"exposure_s": float(exposure_s), "time_s": t0, "target": self.target,
                "w_i": w_i.tolist(), "w_o": w_o.tolist(), "sim_lamp_relative": lamp,
                "seed": self.seed, "material": self.material}  # time_s names the frame: no counter that a resume restarts
        return mosaic, meta, ends

    def _radiance(self, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
        """Radiance per pixel (H, W) in its Bayer channel, for nominal lamp irradiance 1."""
        shape = (self.model.height, self.model.width)
        if self.target == "flat":
            return np.full(shape, WHITE_TILE_REFLECTANCE / np.pi)
        cos_i = max(float(w_i[2]), 0.0)       # light from below the card: unlit
        if w_o[2] <= 1e-3:                    # card seen edge-on: only background
            return np.full(shape, BACKGROUND_REFLECTANCE / np.pi * cos_i)
        white = self.target == "white"
        patch = np.full(3, WHITE_TILE_REFLECTANCE / np.pi) if white else self.ground_truth(w_i, w_o)
        card, cover = self._renderer.view(w_i, w_o, WHITE_MARKER_IDS if white else SAMPLE_MARKER_IDS)
        return (card / np.pi + cover * patch[self._channels]) * cos_i

    def _frame_noise(self, t0: float) -> np.random.Generator:
        """The noise of the frame exposed from nominal time ``t0``: its own stream, derived from the
        seed and that time. No stream is consumed in order, so a frame taken again at the same
        nominal time (a session resumed from the state it was journaled in) has the same noise."""
        return np.random.default_rng([self.seed, int(np.float64(t0).view(np.uint64))])

    def _digitise(self, radiance: np.ndarray, exposure_s: float, rng: np.random.Generator) -> np.ndarray:
        """Electrons -> noisy (``rng``), saturating 14-bit DN mosaic (H, W) uint16."""
        p = self.params
        gain_c = np.asarray(p["channel_gain"])[self._channels]
        electrons = radiance * np.pi * p["signal_e_s"] * gain_c * self._gain * exposure_s
        dark = p["dark_current_e_s"] * exposure_s
        if p["noise"]:
            electrons = rng.poisson(electrons + dark).astype(np.float64)
        else:
            electrons = electrons + dark
        if p["noise"]:
            electrons += p["read_noise_e"] * rng.standard_normal(electrons.shape)
        # the ADC range ends at full well: a full pixel reads exactly the white level
        electrons = np.minimum(electrons, p["full_well_e"])
        dn_per_e = (p["white_level"] - p["black_level"]) / p["full_well_e"]
        dn = np.rint(p["black_level"] + electrons * dn_per_e)
        return np.clip(dn, 0, p["white_level"]).astype(np.uint16)
