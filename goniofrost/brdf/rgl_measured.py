"""Evaluate an RGL tensor file (``.bsdf``) as Mitsuba 3's ``measured`` plugin does, in numpy.

The steps of ``Measured::eval`` (``measured.cpp``, v3.9.1), vectorised over direction pairs; it
returns f cos theta_o, and ``brdf`` divides by cos theta_o. A spectral table is turned into sRGB
once, exactly (docs/decisions/0300-rgl-spectral-to-rgb.md). A missing, mistyped, non-finite or
anisotropic field raises ``MeasuredFileError``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from goniofrost.brdf import cie1931
from goniofrost.brdf.rgl_tensor import TensorFileError, read_tensor_file

# Bump when the evaluation changes: part of the datasets' content ids (the tabulation cache).
EVAL_VERSION = "rgl-measured-v1"
# Float fields and their rank, as measured.cpp checks them (the table is ``rgb`` or ``spectra``).
FLOAT_FIELDS = {"theta_i": 1, "phi_i": 1, "ndf": 2, "sigma": 2, "vndf": 4, "luminance": 4}
# Pairs per chunk: bounds the temporaries (about 40 float64 arrays of this length).
CHUNK_PAIRS = 1 << 16


class MeasuredFileError(TensorFileError):
    """A tensor file that cannot be evaluated as a measured BRDF (names the file, field and what was expected)."""


@dataclass(frozen=True)
class Interpolant:
    """``Marginal2D`` tables of a batch of slices (float64 holding Mitsuba's float32 values).

    data (S, h, w); cond (S, h, w - 1) and marg (S, h - 1) the running integrals (None when the
    table is only evaluated). S = n_phi * n_theta slices, phi-major (the file's order).
    """

    data: np.ndarray
    cond: np.ndarray | None = None
    marg: np.ndarray | None = None


@dataclass(frozen=True)
class MeasuredFile:
    """An isotropic RGL tensor file ready to evaluate.

    theta_i (n_i,), phi_i (n_p,) in rad; ndf, sigma: (n_p', n) tables; vndf: the normalised warp;
    rgb: (S, 3, n, n) the RGB table (a spectral file's already integrated); jacobian: the flag;
    kind "rgb" or "spectral"; wavelengths (n_lambda,) nm of a spectral file (else empty).
    """

    path: str
    theta_i: np.ndarray
    phi_i: np.ndarray
    ndf: np.ndarray
    sigma: np.ndarray
    vndf: Interpolant
    rgb: np.ndarray
    jacobian: bool
    kind: str
    wavelengths: np.ndarray
    description: str

    def domain_text(self) -> str:
        """One line: what the file holds and the incident elevations it covers."""
        lo, hi = np.degrees(self.theta_i[[0, -1]])
        what = "RGB" if self.kind == "rgb" else (f"spectral, {self.wavelengths.size} wavelengths "
                                                 f"{self.wavelengths[0]:g}-{self.wavelengths[-1]:g} nm")
        return f"{what}; theta_i {lo:.1f}-{hi:.1f} deg ({self.theta_i.size} elevations)"


# ----- reading -----------------------------------------------------------------------------------
def load_measured(path) -> MeasuredFile:
    """Read and check a tensor file; raise MeasuredFileError / TensorFileError with one line."""
    fields = read_tensor_file(path)
    source = str(path)
    spectral = "wavelengths" in fields
    table_name = "spectra" if spectral else "rgb"
    for name in (*FLOAT_FIELDS, table_name, "jacobian", "description"):
        if name not in fields:
            raise MeasuredFileError(f"{source}: field {name!r} missing; expected the fields of an RGL measured "
                                    f"BRDF ({', '.join((*FLOAT_FIELDS, table_name, 'jacobian'))})")
    _check_layout(fields, table_name, source)
    phi_i = fields["phi_i"].astype(np.float64)
    if phi_i.size > 2:
        raise MeasuredFileError(f"{source}: anisotropic file: phi_i has {phi_i.size} entries, expected at most 2 "
                                f"(an isotropic measurement); anisotropic files are not supported")
    for name in (*FLOAT_FIELDS, table_name, *(("wavelengths",) if spectral else ())):
        bad = int(np.count_nonzero(~np.isfinite(fields[name])))
        if bad:
            raise MeasuredFileError(f"{source}: field {name!r} holds {bad} NaN or infinite values; expected finite numbers")
    table = fields[table_name].astype(np.float64)
    wavelengths = fields["wavelengths"].astype(np.float64) if spectral else np.zeros(0)
    if spectral:
        table = np.einsum("pilyx,lc->picyx", table, cie1931.spectrum_to_srgb_weights(wavelengths))
    n_slices = phi_i.size * fields["theta_i"].size
    return MeasuredFile(
        path=source, theta_i=fields["theta_i"].astype(np.float64), phi_i=phi_i,
        ndf=fields["ndf"].astype(np.float64), sigma=fields["sigma"].astype(np.float64),
        vndf=build_warp(fields["vndf"].reshape(n_slices, *fields["vndf"].shape[2:])),
        rgb=table.reshape(n_slices, 3, *table.shape[3:]), jacobian=bool(fields["jacobian"][0]),
        kind="spectral" if spectral else "rgb", wavelengths=wavelengths,
        description=bytes(fields["description"]).decode("utf-8", "replace"))


def _check_layout(fields: dict, table_name: str, source: str) -> None:
    """The dtype and shape checks of measured.cpp, each failure named."""
    for name, rank in FLOAT_FIELDS.items():
        _expect(fields[name], np.float32, rank, name, source)
    _expect(fields[table_name], np.float32, 5, table_name, source)
    _expect(fields["jacobian"], np.uint8, 1, "jacobian", source)
    if table_name == "spectra":
        _expect(fields["wavelengths"], np.float32, 1, "wavelengths", source)
    n_p, n_i = fields["phi_i"].size, fields["theta_i"].size
    lum, table = fields["luminance"].shape, fields[table_name].shape
    channels = fields["wavelengths"].size if table_name == "spectra" else 3
    wanted = {"vndf": (n_p, n_i) + fields["vndf"].shape[2:], "luminance": (n_p, n_i, lum[2], lum[2]),
              table_name: (n_p, n_i, channels, lum[2], lum[3]), "jacobian": (1,)}
    for name, shape in wanted.items():
        if fields[name].shape != shape:
            raise MeasuredFileError(f"{source}: field {name!r} has shape {fields[name].shape}, expected {shape}")
    for name in ("ndf", "sigma", "vndf"):
        if min(fields[name].shape[-2:]) < 2:
            raise MeasuredFileError(f"{source}: field {name!r} has shape {fields[name].shape}, expected at least 2 "
                                    f"nodes along each of its last two axes")
    if n_i < 1 or min(lum[2:]) < 2:
        raise MeasuredFileError(f"{source}: theta_i has {n_i} entries and the tables {lum[2:]} nodes, expected "
                                f">= 1 and >= 2")


def _expect(array: np.ndarray, dtype, rank: int, name: str, source: str) -> None:
    if array.dtype != np.dtype(dtype) or array.ndim != rank:
        raise MeasuredFileError(f"{source}: field {name!r} is {array.dtype} of rank {array.ndim}, "
                                f"expected {np.dtype(dtype)} of rank {rank}")


def build_warp(data) -> Interpolant:
    """Normalised data and running integrals of densities (S, h, w), as Marginal2D builds and stores them.

    Sums in float64, stored in float32 (ScalarFloat), read back as float64.
    """
    data = np.asarray(data, dtype=np.float64)
    _, h, w = data.shape
    cond = np.cumsum((0.5 / (w - 1)) * (data[..., :-1] + data[..., 1:]), axis=-1)
    marg = np.cumsum((0.5 / (h - 1)) * (cond[:, :-1, -1] + cond[:, 1:, -1]), axis=-1)
    norm = _float32(1.0 / marg[:, -1])
    return Interpolant(_float32(_float32(data) * norm[:, None, None]), _float32(_float32(cond) * norm[:, None, None]),
                       _float32(_float32(marg) * norm[:, None]))


def _float32(values: np.ndarray) -> np.ndarray:
    """float64 holding the float32 rounding of ``values`` (what Mitsuba stores)."""
    return values.astype(np.float32).astype(np.float64)


# ----- evaluating --------------------------------------------------------------------------------
def eval_cosine_weighted(measured: MeasuredFile, w_i, w_o) -> np.ndarray:
    """f cos theta_o (N, 3) of unit directions (N, 3) (w_i towards the light, w_o the viewer; the
    BRDF is reciprocal), 0 where either is below the horizon: Mitsuba's ``eval``."""
    w_i, w_o = (np.asarray(w, dtype=np.float64).reshape(-1, 3) for w in (w_i, w_o))
    out = np.zeros((len(w_i), 3))
    for start in range(0, len(w_i), CHUNK_PAIRS):
        stop = start + CHUNK_PAIRS
        out[start:stop] = _eval_chunk(measured, w_i[start:stop], w_o[start:stop])
    return out


def brdf(measured: MeasuredFile, w_i, w_o) -> np.ndarray:
    """The BRDF f (N, 3) in 1/sr: Mitsuba's eval divided by the cos theta_o the tables hold."""
    w_o = np.asarray(w_o, dtype=np.float64).reshape(-1, 3)
    fcos = eval_cosine_weighted(measured, w_i, w_o)
    cos_o = w_o[:, 2]
    return np.where(cos_o[:, None] > 0, fcos / np.where(cos_o > 0, cos_o, 1.0)[:, None], 0.0)


def _eval_chunk(measured: MeasuredFile, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    active = (w_i[:, 2] > 0) & (w_o[:, 2] > 0)
    m = w_i + w_o
    m /= np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
    theta_i, phi_i = _elevation(w_i), np.arctan2(w_i[:, 1], w_i[:, 0])
    theta_m, phi_m = _elevation(m), np.arctan2(m[:, 1], m[:, 0])
    u_wi = np.stack([_theta2u(theta_i), _phi2u(phi_i)], -1)
    u_phi = _phi2u(phi_m - phi_i)
    u_m = np.stack([_theta2u(theta_m), u_phi - np.floor(u_phi)], -1)
    slices, weights = slice_weights(measured, phi_i, theta_i)
    sample = invert(measured.vndf, u_m, slices, weights)
    out = eval_table(measured.rgb, sample, slices, weights)
    if measured.jacobian:
        scale = _bilinear(measured.ndf, u_m) / (4.0 * _bilinear(measured.sigma, u_wi))
        out *= scale[:, None]
    return np.where(active[:, None], out, 0.0)


def _elevation(d: np.ndarray) -> np.ndarray:
    dist = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + (d[:, 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, -1.0, 1.0))


def _theta2u(theta):
    return np.sqrt(theta * (2.0 / np.pi))


def _phi2u(phi):
    return (phi + np.pi) / (2.0 * np.pi)


def slice_weights(measured: MeasuredFile, phi_i: np.ndarray, theta_i: np.ndarray):
    """The slices (N, 4) and weights (N, 4) of each point: linear in phi_i then theta_i, clamped
    at the ends (``Distribution2D::interpolate_weights``; one node: weight 1)."""
    p0, pw = _interval(measured.phi_i, phi_i)
    t0, tw = _interval(measured.theta_i, theta_i)
    n_i = measured.theta_i.size
    p1, t1 = np.minimum(p0 + 1, measured.phi_i.size - 1), np.minimum(t0 + 1, n_i - 1)
    if measured.phi_i.size == 1:  # one azimuth: only theta_i interpolates (half the gathers)
        return np.stack([t0, t1], -1), np.stack([1 - tw, tw], -1)
    slices = np.stack([p0 * n_i + t0, p0 * n_i + t1, p1 * n_i + t0, p1 * n_i + t1], -1)
    weights = np.stack([(1 - pw) * (1 - tw), (1 - pw) * tw, pw * (1 - tw), pw * tw], -1)
    return slices, weights


def _interval(nodes: np.ndarray, x: np.ndarray):
    """Lower node index and weight of the upper one (math::find_interval, then clip to [0, 1])."""
    if nodes.size == 1:
        return np.zeros(x.shape, np.int64), np.zeros(x.shape)
    i0 = np.clip(np.searchsorted(nodes, x, side="left") - 1, 0, nodes.size - 2)
    p0, p1 = nodes[i0], nodes[i0 + 1]
    return i0, np.clip((x - p0) / (p1 - p0), 0.0, 1.0)


def _lookup(table: np.ndarray, slices, weights, *index) -> np.ndarray:
    """sum_k weights[:, k] table[slices[:, k], *index]: a value interpolated across slices."""
    out = weights[:, 0] * table[(slices[:, 0], *index)]
    for k in range(1, slices.shape[1]):
        out = out + weights[:, k] * table[(slices[:, k], *index)]
    return out


def invert(warp: Interpolant, u: np.ndarray, slices, weights) -> np.ndarray:
    """``Marginal2D::invert_continuous`` (normalised) of points u (N, 2) = (x, y): (N, 2)."""
    _, h, w = warp.data.shape
    s = np.clip(u, 0.0, 1.0) * np.array([w - 1, h - 1])
    px = np.minimum(s[:, 0].astype(np.int64), w - 2)
    py = np.minimum(s[:, 1].astype(np.int64), h - 2)
    fx, fy = s[:, 0] - px, s[:, 1] - py

    def get(table: np.ndarray, *index) -> np.ndarray:
        return _lookup(table, slices, weights, *index)

    v00, v10 = get(warp.data, py, px), get(warp.data, py, px + 1)
    v01, v11 = get(warp.data, py + 1, px), get(warp.data, py + 1, px + 1)
    c0, c1 = v00 + (v01 - v00) * fy, v10 + (v11 - v10) * fy
    x = fx * (c0 + (c1 - c0) * (0.5 * fx)) / (w - 1)
    before = np.maximum(px - 1, 0)
    prev = get(warp.cond, py, before) + (get(warp.cond, py + 1, before) - get(warp.cond, py, before)) * fy
    x = x + np.where(px > 0, prev, 0.0)
    r0, r1 = get(warp.cond, py, w - 2), get(warp.cond, py + 1, w - 2)
    x = x / (r0 + (r1 - r0) * fy)
    y = fy * (r0 + (r1 - r0) * (0.5 * fy)) / (h - 1)
    y = y + np.where(py > 0, get(warp.marg, np.maximum(py - 1, 0)), 0.0)
    return np.stack([x, y], -1)


def eval_table(table: np.ndarray, pos: np.ndarray, slices, weights) -> np.ndarray:
    """``Marginal2D<3>::eval`` (not normalised) of a (S, C, h, w) table at points (N, 2): (N, C)."""
    _, channels, h, w = table.shape
    s = np.clip(pos, 0.0, 1.0) * np.array([w - 1, h - 1])
    px = np.minimum(s[:, 0].astype(np.int64), w - 2)
    py = np.minimum(s[:, 1].astype(np.int64), h - 2)
    fx, fy = (s[:, 0] - px)[:, None], (s[:, 1] - py)[:, None]
    def corner(dy: int, dx: int) -> np.ndarray:
        return sum(weights[:, k, None] * table[slices[:, k], :, py + dy, px + dx] for k in range(slices.shape[1]))

    v00, v10, v01, v11 = corner(0, 0), corner(0, 1), corner(1, 0), corner(1, 1)
    top, bottom = v00 + (v10 - v00) * fx, v01 + (v11 - v01) * fx
    return top + (bottom - top) * fy


def _bilinear(table: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """``Marginal2D<0>::eval`` of a (h, w) table at points (N, 2) = (x along w, y along h)."""
    one = np.zeros((len(pos), 1), np.int64)
    return eval_table(table[None, None], pos, one, np.ones((len(pos), 1)))[:, 0]


def load_or_explain(path) -> MeasuredFile:
    """``load_measured`` with a missing file said plainly (the dataset's entry point)."""
    if not Path(path).is_file():
        raise MeasuredFileError(f"{path}: no such file (expected an RGL tensor file, .bsdf)")
    return load_measured(path)
