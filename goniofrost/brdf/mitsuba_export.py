"""Export a tabulated isotropic BRDF to the RGL tensor format that Mitsuba 3 renders (RGB form).

Builds the fields of Dupuy and Jakob 2018 from the table itself (NDF, sigma, VNDF, ``rgb``), so that
Mitsuba's eval returns the table's value at every node; Mitsuba is not needed. Options:
``ExportOptions``. The steps: docs/explanations/mitsuba-export.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from goniofrost.brdf import marginal2d
from goniofrost.brdf.merl_file import read_merl_complete
from goniofrost.brdf.rgl_tensor import write_tensor_file
from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid, dirs_to_half_diff

# Rec. 709 luminance of linear RGB, as mi.luminance.
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
# Floor of the NDF relative to its peak: keeps 4 sigma / D finite where the retro-reflection is 0.
NDF_FLOOR = 1e-6
# Quadrature points per NDF interval for sigma (D is linear in u there; the kernel is smooth).
SIGMA_SUBSTEPS = 8
POWER_ITERATIONS = 200
POWER_TOLERANCE = 1e-12


class ExportError(GoniofrostError, ValueError):
    """A BRDF table that cannot be exported (names the source and what is wrong)."""


@dataclass(frozen=True)
class ExportOptions:
    """Resolutions of the exported fields and the shape of the VNDF warp.

    theta_i: incident elevations; ndf: NDF and sigma nodes in u_theta; vndf_theta, vndf_phi:
    VNDF nodes in u_theta and relative u_phi; sample: rgb/luminance nodes per side of each
    theta_i slice. The VNDF warp follows D**warp_exponent mixed with a uniform NDF (1/pi) at
    uniform_share; (1.0, 0.0) is the paper's VNDF of D itself. Reasons for the defaults: the
    module docstring (step 4) and README ("Export to Mitsuba 3"); measured by
    benchmarks/mitsuba_export.py.
    """

    theta_i: int = 48
    ndf: int = 91
    vndf_theta: int = 91
    vndf_phi: int = 64
    sample: int = 128
    warp_exponent: float = 0.75
    uniform_share: float = 0.1

    def __post_init__(self) -> None:
        for name in ("theta_i", "ndf", "vndf_theta", "vndf_phi", "sample"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 2:
                raise ExportError(f"ExportOptions.{name}: expected an integer >= 2, found {value!r}")
        if not 0.0 < self.warp_exponent <= 1.0:
            raise ExportError(f"ExportOptions.warp_exponent: expected a number in (0, 1], found {self.warp_exponent!r}")
        if not 0.0 <= self.uniform_share < 1.0:
            raise ExportError(f"ExportOptions.uniform_share: expected a fraction in [0, 1), found {self.uniform_share!r}")


DEFAULT_OPTIONS = ExportOptions()


@dataclass(frozen=True)
class Ndf:
    """The microfacet distribution recovered from the table, on nodes u = linspace(0, 1, n).

    ``d`` (n,) the NDF (1/sr) and ``sigma`` (n,) the projected area at theta = u^2 pi / 2, both
    float32 as stored (Mitsuba interpolates the stored values), sigma[0] = 1; ``warp`` (n,)
    the NDF that shapes the VNDF warp (also normalised to sigma(normal) = 1).
    """

    u: np.ndarray
    d: np.ndarray
    sigma: np.ndarray
    warp: np.ndarray

    def d_at(self, u) -> np.ndarray:
        """D at u_theta (linear in u, as Mitsuba's bilinear ``ndf`` field)."""
        return np.interp(u, self.u, self.d.astype(np.float64))

    def sigma_at(self, u) -> np.ndarray:
        """sigma at u_theta (linear in u, as Mitsuba's ``sigma`` field)."""
        return np.interp(u, self.u, self.sigma.astype(np.float64))

    def warp_at(self, u) -> np.ndarray:
        """The warp's NDF at u_theta (linear in u)."""
        return np.interp(u, self.u, self.warp)


# ----- the table ---------------------------------------------------------------------------
def prepared_table(brdf, grid: MerlGrid, source: str = "BRDF") -> np.ndarray:
    """Check a (grid.size, 3) BRDF in 1/sr and return it ready for lookups (float64, no NaN).

    Raises ExportError for a wrong shape, inf, negative values or no positive value on a valid
    cell. Missing values (NaN) on valid cells become 0; invalid cells take the last valid
    cell along theta_d (module docstring).
    """
    table = np.asarray(brdf, dtype=np.float64)
    if table.shape != (grid.size, 3):
        raise ExportError(f"{source}: expected a BRDF table of shape {(grid.size, 3)}, found {table.shape}")
    if np.isinf(table).any():
        raise ExportError(f"{source}: {int(np.isinf(table).sum())} infinite values; expected finite BRDF values")
    valid = table[grid.valid_mask]
    if (valid < 0).any():
        raise ExportError(f"{source}: {int((valid < 0).sum())} negative values on valid cells; expected >= 0 "
                          f"(missing values are NaN)")
    if not (np.nan_to_num(valid) > 0).any():
        raise ExportError(f"{source}: no valid value: every valid cell is missing or zero")
    return _extend_beyond_horizon(np.nan_to_num(table), grid)


def _extend_beyond_horizon(table: np.ndarray, grid: MerlGrid) -> np.ndarray:
    """Fill each invalid cell with the last valid cell of its (theta_h, phi_d) column.

    Along theta_d the valid cells of a column are a prefix (z of w_i and w_o is A cos td +
    B sin td, positive on an interval that starts at td = 0), so the fill index is
    min(i_td, count - 1).
    """
    valid = grid.valid_mask.reshape(grid.shape)
    count = valid.sum(axis=1, keepdims=True)                       # (n_th, 1, n_pd)
    i_td = np.arange(grid.n_td)[None, :, None]
    source_td = np.minimum(i_td, np.maximum(count - 1, 0))
    flat = grid.flat_index(np.arange(grid.n_th)[:, None, None], source_td, np.arange(grid.n_pd)[None, None, :])
    return table[flat.reshape(-1)]


def lookup(table: np.ndarray, grid: MerlGrid, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """BRDF (..., 3) of a prepared table at unit directions (..., 3): the cell containing them."""
    return table[grid.angles_to_flat(*dirs_to_half_diff(w_i, w_o))]


# ----- steps 1 and 2: NDF and sigma ----------------------------------------------------------
def u_to_theta(u):
    """Elevation (rad) of Mitsuba's u-coordinate: theta = u^2 pi / 2."""
    return np.square(u) * (np.pi / 2)


def theta_to_u(theta):
    """Mitsuba's u-coordinate of an elevation (rad): u = sqrt(2 theta / pi)."""
    return np.sqrt(np.asarray(theta) * (2 / np.pi))


def elevation_dir(theta) -> np.ndarray:
    """Unit directions (..., 3) at elevation theta (rad) in the x-z plane (phi = 0)."""
    theta = np.asarray(theta, dtype=np.float64)
    return np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)


def recover_ndf(table: np.ndarray, grid: MerlGrid, options: ExportOptions = DEFAULT_OPTIONS) -> Ndf:
    """The NDF of the retro-reflection slice by power iteration, sigma and the warp's NDF (steps 1-2)."""
    u = np.linspace(0.0, 1.0, options.ndf)
    w = elevation_dir(u_to_theta(u))
    retro = lookup(table, grid, w, w) @ LUMINANCE * w[:, 2]        # f(w, w) cos theta
    area = projected_area_matrix(u)                                # sigma = area @ D
    d = _power_iteration(retro[:, None] * area) if (retro > 0).any() else np.ones(u.size)
    d = np.maximum(d, NDF_FLOOR * d.max())
    d = (d / (area @ d)[0]).astype(np.float32)                     # sigma(normal) = 1
    tempered = d.astype(np.float64) ** options.warp_exponent
    warp = (1.0 - options.uniform_share) * tempered / (area @ tempered)[0] + options.uniform_share / np.pi
    return Ndf(u, d, (area @ d.astype(np.float64)).astype(np.float32), warp)


def _power_iteration(kernel: np.ndarray) -> np.ndarray:
    """The eigenvector (>= 0, max 1) of a positive matrix's largest eigenvalue."""
    v = np.ones(kernel.shape[0])
    for _ in range(POWER_ITERATIONS):
        nxt = kernel @ v
        nxt /= nxt.max()
        if np.max(np.abs(nxt - v)) < POWER_TOLERANCE:
            return nxt
        v = nxt
    return v


def projected_area_matrix(u: np.ndarray) -> np.ndarray:
    """Matrix A (n, n): sigma(theta(u_j)) = sum_k A[j, k] D_k for an isotropic D linear in u.

    sigma(w) = int_0^{pi/2} D(theta_m) sin theta_m Phi(theta, theta_m) dtheta_m with
    Phi = int_0^{2 pi} <w, m>+ dphi in closed form; midpoint rule in u (dtheta = pi u du).
    """
    n = u.size
    fine = (np.arange(SIGMA_SUBSTEPS * (n - 1)) + 0.5) / (SIGMA_SUBSTEPS * (n - 1))
    theta_m = u_to_theta(fine)
    weight = np.sin(theta_m) * np.pi * fine / (SIGMA_SUBSTEPS * (n - 1))
    kernel = _azimuthal_cosine(u_to_theta(u)[:, None], theta_m[None, :]) * weight
    return kernel @ _linear_interpolation_matrix(u, fine)


def _azimuthal_cosine(theta, theta_m) -> np.ndarray:
    """int_0^{2 pi} max(0, cos t cos t_m + sin t sin t_m cos phi) dphi, elementwise."""
    a = np.cos(theta) * np.cos(theta_m)
    b = np.sin(theta) * np.sin(theta_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi0 = np.arccos(np.clip(-a / b, -1.0, 1.0))
    partial = 2.0 * (a * phi0 + b * np.sin(phi0))
    return np.where(a >= b, 2 * np.pi * a, np.where(a <= -b, 0.0, partial))


def _linear_interpolation_matrix(nodes: np.ndarray, x: np.ndarray) -> np.ndarray:
    """P (len(x), len(nodes)) with P @ values = np.interp(x, nodes, values)."""
    k = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, nodes.size - 2)
    t = (x - nodes[k]) / (nodes[k + 1] - nodes[k])
    p = np.zeros((x.size, nodes.size))
    p[np.arange(x.size), k] = 1.0 - t
    p[np.arange(x.size), k + 1] = t
    return p


# ----- step 3: incident elevations -----------------------------------------------------------
def incident_elevations(ndf: Ndf, n: int) -> np.ndarray:
    """n elevations (rad) from 0 to pi/2 with sigma uniformly spaced (paper; Falcor's computeTheta).

    sigma is made non-increasing first; a flat sigma falls back to uniform elevations.
    """
    sigma = np.minimum.accumulate(ndf.sigma.astype(np.float64))
    if sigma[0] - sigma[-1] < 1e-3:
        return np.linspace(0.0, np.pi / 2, n)
    targets = np.linspace(sigma[0], sigma[-1], n)
    u = np.interp(-targets, -sigma, ndf.u)                         # sigma decreasing in u
    u[0], u[-1] = 0.0, 1.0
    return u_to_theta(np.maximum.accumulate(u))


# ----- steps 4 and 5: VNDF, rgb, luminance ---------------------------------------------------
def vndf_tables(ndf: Ndf, theta_i: np.ndarray, options: ExportOptions) -> np.ndarray:
    """VNDF densities (n_theta_i, vndf_phi, vndf_theta) in u-space, each slice normalised."""
    u_t = np.linspace(0.0, 1.0, options.vndf_theta)
    u_p = np.linspace(0.0, 1.0, options.vndf_phi)
    m = _normal(u_t[None, :], u_p[:, None])                        # (phi, theta, 3)
    w_i = elevation_dir(theta_i)                                   # (n_i, 3)
    cosine = np.maximum(np.einsum("pte,ie->ipt", m, w_i), 0.0)
    jacobian = 2 * np.pi ** 2 * u_t * np.sin(u_to_theta(u_t))
    vndf = ndf.warp_at(u_t) * jacobian * cosine
    return vndf / _bilinear_integral(vndf)[:, None, None]


def _normal(u_theta, u_phi) -> np.ndarray:
    """Micro-normals (..., 3) of Mitsuba's u-coordinates (azimuth relative to phi_i = 0)."""
    theta, phi = u_to_theta(u_theta), (2.0 * u_phi - 1.0) * np.pi
    theta, phi = np.broadcast_arrays(theta, phi)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def _bilinear_integral(data: np.ndarray) -> np.ndarray:
    """Integral over the unit square of bilinear interpolants (S, h, w) -> (S,)."""
    h, w = data.shape[-2:]
    cells = data[:, :-1, :-1] + data[:, 1:, :-1] + data[:, :-1, 1:] + data[:, 1:, 1:]
    return cells.sum(axis=(1, 2)) / (4.0 * (h - 1) * (w - 1))


def measured_tables(table, grid, ndf: Ndf, theta_i, vndf, options: ExportOptions):
    """``rgb`` (n_theta_i, 3, n, n) and ``luminance`` (n_theta_i, n, n) on the warped square."""
    n = options.sample
    s = np.linspace(0.0, 1.0, n)
    points = np.stack(np.broadcast_arrays(s[None, :], s[:, None]), -1).reshape(1, n * n, 2)
    u_m, _ = marginal2d.sample(marginal2d.build(vndf), np.repeat(points, theta_i.size, axis=0))
    m = _normal(u_m[..., 0], u_m[..., 1])                          # (n_i, n*n, 3)
    w_i = np.broadcast_to(elevation_dir(theta_i)[:, None, :], m.shape)
    cos_im = np.sum(w_i * m, axis=-1)
    w_o = 2.0 * cos_im[..., None] * m - w_i
    above = (w_o[..., 2] > 0) & (cos_im > 0)
    f = lookup(table, grid, w_i, np.where(above[..., None], w_o, elevation_dir(0.0)))
    scale = 4.0 * ndf.sigma_at(theta_to_u(theta_i))[:, None] / ndf.d_at(u_m[..., 0])
    rgb = np.where(above[..., None], f * (w_o[..., 2] * scale)[..., None], 0.0)
    rgb = rgb.reshape(theta_i.size, n, n, 3).transpose(0, 3, 1, 2)
    # Luminance sampling makes the pdf follow f cos theta_o: lum(s) ~ Y(f cos) / p_warp(w_o),
    # i.e. Y(rgb) D / D_warp (rgb holds f cos 4 sigma / D; p_warp = D_warp / (4 sigma_warp)).
    ratio = (ndf.d_at(u_m[..., 0]) / ndf.warp_at(u_m[..., 0])).reshape(theta_i.size, n, n)
    luminance = np.einsum("c,icyx->iyx", LUMINANCE, rgb) * ratio
    empty = luminance.sum(axis=(1, 2)) <= 0
    luminance[empty] = 1.0                                         # nothing to follow: sample the VNDF alone
    return rgb, luminance


# ----- the whole export ----------------------------------------------------------------------
def build_fields(brdf, grid: MerlGrid, options: ExportOptions = DEFAULT_OPTIONS,
                 description: str = "goniofrost export", source: str = "BRDF") -> dict:
    """The fields of the tensor file (name -> float32/uint8 array or str), in file order."""
    table = prepared_table(brdf, grid, source)
    ndf = recover_ndf(table, grid, options)
    theta_i = incident_elevations(ndf, options.theta_i).astype(np.float32).astype(np.float64)
    vndf = vndf_tables(ndf, theta_i, options).astype(np.float32)
    rgb, luminance = measured_tables(table, grid, ndf, theta_i, vndf.astype(np.float64), options)
    return {
        "description": description,
        "phi_i": np.zeros(1, np.float32),                          # one azimuth: isotropic
        "theta_i": theta_i.astype(np.float32),
        "ndf": np.repeat(ndf.d[None, :], 2, axis=0),                # (phi, theta); constant in phi
        "sigma": np.repeat(ndf.sigma[None, :], 2, axis=0),
        "vndf": vndf[None],
        "luminance": luminance[None].astype(np.float32),
        "rgb": rgb[None].astype(np.float32),
        "jacobian": np.ones(1, np.uint8),                           # rgb is divided by ndf / (4 sigma)
    }


def export_mitsuba(path, brdf, grid: MerlGrid, options: ExportOptions = DEFAULT_OPTIONS,
                   source: str = "BRDF") -> dict:
    """Write a (grid.size, 3) BRDF in 1/sr (NaN = missing) as an RGL tensor file; return the fields."""
    description = (f"isotropic BRDF from {source}, exported by goniofrost "
                   f"(MERL grid {grid.n_th}x{grid.n_td}x{grid.n_pd}; theta_i {options.theta_i}, "
                   f"ndf {options.ndf}, vndf {options.vndf_phi}x{options.vndf_theta}, rgb {options.sample}x{options.sample}; "
                   f"VNDF warp D^{options.warp_exponent:g} + {options.uniform_share:g} uniform)")
    fields = build_fields(brdf, grid, options, description, source)
    write_tensor_file(path, fields)
    return fields


def export_binary_file(binary, out, options: ExportOptions = DEFAULT_OPTIONS) -> dict:
    """Export a MERL .binary file to an RGL tensor file ``out``; nothing is written on error."""
    brdf, grid = read_merl_complete(binary)
    return export_mitsuba(out, brdf, grid, options, source=str(binary))

