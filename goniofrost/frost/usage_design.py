"""The scene-aware Bayesian design: the expected error of what a scene sees, in the plain design's form.

With u (n_valid,) a scene's use of every cell (sum 1) the error is trace(M Sigma),
M = D^T diag(u) D; ``scene_prior`` and ``rotate`` change basis so the plain greedy design is the
scene-weighted one. Weights u g^p exp(t p^2 v / 2) (``design_usage``, ``BANDS``). Why:
docs/explanations/scene-aware-design.md.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from goniofrost.frost.posterior import prior_variance

# Rows of D handled at once (float64 copies of 64k x 60 = 31 MB).
CHUNK_ROWS = 1 << 16
# The exponent p of the sensitivity g in the design's weights u g^p exp(t p^2 v / 2) (module doc) and
# the prior spread t, per number of samples m (BANDS). p: 0 weighs the mapped error the scene sees,
# 2 its first-order image error; t: 0 weighs g at the prior mean, 1 the prior's expected g^p
# (``linear_usage``). Chosen at m = 10, 20 and 40 on validation materials by benchmarks/scene_design.py
# (docs/decisions/0007-scene-aware-design-bands.md); each m takes the choice of the nearest measured m
# on a log scale, so the band edges are sqrt(10 * 20) = 14.1 and sqrt(20 * 40) = 28.3.
FEW_SAMPLES = 14
MANY_SAMPLES = 28
POWER_FEW = 1.0
POWER_MANY = 0.5
POWER_MOST = 0.5
SPREAD_FEW = 1.0
SPREAD_MANY = 1.0
SPREAD_MOST = 1.0
# The floor F on the design weights' effective cells 1 / sum w^2 (``floor_spread``): with F > 0 the
# band's t is the most the spread may be, and each scene's t is the largest in [0, t] whose weights
# keep F effective cells (0: no floor, t itself). A band's floor belongs to its own power p (BANDS):
# up to FEW_SAMPLES the floor binds the p = 1 designs only (``spread_floor``). F counts cells of the
# model's grid, so a coarser grid keeps less spread.
FLOOR_FEW = 6000.0
FLOOR_MANY = 0.0
FLOOR_MOST = 0.0
# (the last m of the band or None, p, t, F), in increasing m
BANDS = ((FEW_SAMPLES, POWER_FEW, SPREAD_FEW, FLOOR_FEW), (MANY_SAMPLES, POWER_MANY, SPREAD_MANY, FLOOR_MANY),
         (None, POWER_MOST, SPREAD_MOST, FLOOR_MOST))
# A power per scene from MANY_SAMPLES + 1 samples: each scene's p is the largest of POWERS_MOST whose
# weights (at the band's t and floor) keep POWER_FLOOR_MOST effective cells, POWER_MOST when none
# larger does (``scene_power``). The count is of the model's grid's cells, as FLOOR_FEW's.
POWERS_MOST = (0.5, 0.75, 1.0)
POWER_FLOOR_MOST = 4000.0
# Each band's powers (by its last m): a set and the effective cells a power above the set's smallest
# must keep (``scene_power``); the band 15-28 takes the last band's. Up to FEW_SAMPLES a scene of
# p = 1 (POWER_FEW) then takes the band's floor FLOOR_FEW on t, one of 0.5 or 0.75 t = 1 without a
# floor: this keeps the grazing plane's fabrics and diffuse materials off p = 1, which put them at
# up to 8.9 times the scene-blind design's error at m = 10.
POWERS_FEW = (0.5, 0.75, 1.0)
POWER_CELLS_FEW = 3300.0
BAND_POWERS = {FEW_SAMPLES: (POWERS_FEW, POWER_CELLS_FEW), MANY_SAMPLES: (POWERS_MOST, POWER_FLOOR_MOST),
               None: (POWERS_MOST, POWER_FLOOR_MOST)}
# A mix of two designs up to FEW_SAMPLES: a scene whose power (``scene_power``) is below the band's
# own p = 1 weighs w = a w(MIX_DESIGN) + (1 - a) w(its p, t = 1, no floor), each part summing to 1
# (``mixed_weights``), so that its samples go both to the specular cells the p = 1 design finds and
# to the broad region of the smaller power. MIX_FEW is the share a (0: no mix), fixed at 0.5 before
# any result, not tuned; a scene of p = 1 is never mixed (``design_mix``).
MIX_FEW = 0.5
# The design mixed in: (p, largest t, F) of the band up to FEW_SAMPLES for its own power.
MIX_DESIGN = (POWER_FEW, SPREAD_FEW, FLOOR_FEW)
BAND_MIX = {FEW_SAMPLES: MIX_FEW, MANY_SAMPLES: 0.0, None: 0.0}
# The prior spread t of a mixed design's own part (its p < 1; ``mixed_weights``) up to FEW_SAMPLES:
# 1, the prior's expected g^p (t = 0 was measured worse). The key of a mixed design's calibration
# (``design_key``) holds this t, so designs of different own t never share a calibration.
MIX_SPREAD_FEW = 1.0
BAND_MIX_SPREAD = {FEW_SAMPLES: MIX_SPREAD_FEW, MANY_SAMPLES: SPREAD_MANY, None: SPREAD_MOST}
# The bisection's tolerance on t in ``floor_spread`` (t is within this of the largest t keeping the floor).
SPREAD_TOLERANCE = 0.01
# The power of the earlier rule, one for every m (the benchmark compares against it).
SENSITIVITY_POWER = 0.5
# The scene's share a of the design's weights (1 - a) / n + a u g^p / sum (``design_usage``): 1 the
# scene alone, 0 the plain design. A hedge against a misspecified posterior at few samples was
# tried: on the 129 training materials in 4 inner folds (benchmarks/scene_design.py) a = 1 had the
# lowest worst-scene image error at m = 10, 20 and 40 (a = 0.3 to 0.9 were worse at every m).
HEDGE = 1.0


@dataclass(frozen=True, eq=False)  # compared by identity: ``usage`` is an array
class SceneDesign:
    """What ``bayes_selection.select_bayes`` designs for a scene: ``usage`` float (n_valid,), the
    scene's use of every cell, sum 1. The rest are the weights u g^p exp(t p^2 v / 2) mixed in
    by ``hedge`` (1 the scene alone, 0 the plain design): ``sensitivity_power`` p, ``prior_spread``
    t, ``spread_floor`` F (effective cells, 0 none), ``mix`` the share a of MIX_DESIGN and
    ``mix_spread`` its own part's t; each None takes the band's default for m (``BANDS``, as
    select_bayes's docstring says). ``uniform_is_plain`` False: a uniform map takes the long way
    through the change of basis (for tests)."""

    usage: np.ndarray
    uniform_is_plain: bool = True
    sensitivity_power: float | None = None
    hedge: float = HEDGE
    prior_spread: float | None = None
    spread_floor: float | None = None
    mix: float | None = None
    mix_spread: float | None = None


@dataclass(frozen=True)
class DesignChoice:
    """The weights of one scene design with every default resolved
    (``bayes_selection.design_options``): ``power`` p (None: no scene), ``spread`` t (of the
    design's own part when mixed), ``floor`` F on the effective cells (0 none) and ``mix`` the
    share a of MIX_DESIGN (0 none). ``key``: its calibration's key, which the plan records."""

    power: float | None
    spread: float = 0.0
    floor: float = 0.0
    mix: float = 0.0

    @property
    def key(self) -> tuple:
        return design_key(self.power, self.spread, self.floor, self.mix)


def band(m: int) -> tuple:
    """(last m of the band or None, p, t, F) of BANDS for a design of m samples."""
    if not isinstance(m, (int, np.integer)) or m < 1:
        raise ValueError(f"usage_design: the number of samples m must be a positive integer, found {m!r}")
    return next(b for b in BANDS if b[0] is None or m <= b[0])


def sensitivity_power(m: int) -> float:
    """The band's power p of the design's weights u g^p for a design of m samples: POWER_FEW = 1
    for m <= FEW_SAMPLES = 14, POWER_MANY = POWER_MOST = 0.5 above (where the numbers come from: the
    comment at FEW_SAMPLES). A scene's design (``plan --samples m --usage``) takes its own power of
    the band's set (``scene_power``): up to FEW_SAMPLES 1 or a smaller one (0.5, 0.75), above it
    0.5 or a larger one. A
    design stopped by an error target instead (``plan --max-error``) has the power of the number of
    samples it ends with (``bayes_selection.select_bayes``)."""
    return band(m)[1]


def scene_power(model, usage: np.ndarray, m: int, variance=None) -> float:
    """The power p a scene design of m samples uses for ``usage`` (what ``select_bayes`` does
    without one): the largest of the band's powers (BAND_POWERS) whose scene weights
    u g^p exp(t p^2 v / 2) at the band's t, without a floor, keep the band's count of effective
    cells (``largest_power``), the smallest when none larger does; the band's p
    (``sensitivity_power``) for a uniform map (the plain design). Costs a pass over the dictionary
    (the cells' prior variance; ``variance``: see ``design_weights``) and one set of weights per
    power tried."""
    last, power, spread, _ = band(m)
    if is_uniform(np.asarray(usage, dtype=np.float64)):
        return power
    powers, cells = BAND_POWERS[last]
    return largest_power(model, usage, powers, cells, spread, 0.0, variance=variance)


def largest_power(model, usage: np.ndarray, powers, cells: float, spread: float = 0.0, floor: float = 0.0,
                  hedge: float = 1.0, variance=None) -> float:
    """The largest of ``powers`` whose design weights for ``usage`` (``design_weights`` at
    ``hedge``, ``spread`` and ``floor``) keep at least ``cells`` effective cells 1 / sum w^2; the
    smallest when none larger does, or for a uniform map (``variance``: see ``design_weights``)."""
    usage = np.asarray(usage, dtype=np.float64)
    ordered = sorted(powers, reverse=True)
    if is_uniform(usage):
        return ordered[-1]
    variance = variance or cell_variance_of(model)  # one pass over D for every power tried
    for p in ordered[:-1]:
        if effective_cells(design_weights(model, usage, p, hedge, spread, floor, variance)[0]) >= cells:
            return p
    return ordered[-1]


def cell_variance_of(model):
    """A function returning the model's cells' prior variance (``prior_cell_variance``: a pass over
    the dictionary), computed at its first call and kept: the weights of one selection's designs
    and of its power choice share that pass."""
    return functools.cache(lambda: prior_cell_variance(model.dictionary, prior_variance(model)))


def prior_spread(m: int) -> float:
    """The prior spread t of the design's weights for a design of m samples (``select_bayes``'s
    default): 1 at every m; for m <= FEW_SAMPLES the most it may be, each scene's t the largest
    that keeps the band's floor on the effective cells (``spread_floor``; the comment at
    FEW_SAMPLES)."""
    return band(m)[2]


def spread_floor(m: int, power: float | None = None) -> float:
    """The floor F on the effective cells (cells) of the design's weights for a design of m samples
    at ``power`` (``select_bayes``'s default; 0: no floor, the band's t as it is; ``floor_spread``):
    the band's floor for the band's own power (None: that power), 0 for a scene's other power of
    the band (BAND_POWERS; up to FEW_SAMPLES the floor binds p = 1 only)."""
    _, own, _, floor = band(m)
    return floor if power is None or power == own else 0.0


def design_mix(m: int, power: float, share: float | None = None) -> float:
    """The share a of MIX_DESIGN in a scene design of m samples at ``power`` (``mixed_weights``):
    ``share`` (None: the band's, BAND_MIX) when ``power`` is not the band's own p, 0 when it is (a
    scene of the band's own power keeps its design)."""
    last, own, _, _ = band(m)
    share = BAND_MIX[last] if share is None else check_share(share)
    return 0.0 if power == own else share


def check_share(share) -> float:
    """``share`` as a float when it is a share of the mixed-in design (in [0, 1]), else ValueError in
    one line."""
    share = float(share)
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"usage_design: the share of the mixed-in design must be in [0, 1], found {share!r}")
    return share


def mix_spread(m: int) -> float:
    """The prior spread t of the own part of a mixed scene design of m samples (BAND_MIX_SPREAD;
    ``select_bayes``'s default when its design is mixed, ``design_mix`` > 0)."""
    return BAND_MIX_SPREAD[band(m)[0]]


def design_key(power: float, spread: float, floor: float, mix: float = 0.0) -> tuple:
    """The key of a scene design's calibration (and of its weights): (p, largest t, F), with the
    share a of MIX_DESIGN appended when the design is mixed (a > 0; ``mixed_weights``), so a mixed
    design never shares an unmixed one's calibration."""
    return (power, spread, floor) + ((mix,) if mix else ())


def _band_of_power(power: float) -> tuple:
    """(t, F) of the first band whose power, or one of whose powers (BAND_POWERS), is ``power``,
    F the band's floor when ``power`` is the band's own p, else 0; (0, 0) when none is."""
    return next(((t, f if power == p else 0.0) for last, p, t, f in BANDS
                 if power == p or power in BAND_POWERS[last][0]), (0.0, 0.0))


def spread_of_power(power: float) -> float:
    """The prior spread of the first band whose power, or one of whose powers (BAND_POWERS), is
    ``power`` (BANDS; 0 when none is): what a design of that power uses by default
    (``usage_calibration.calibrate_scene`` without a spread). p = 1 is the first band's (t up to 1,
    F = 6,000) and one of the later bands' (t = 1, no floor), whose weights differ where t = 1 keeps
    from POWER_FLOOR_MOST to FLOOR_FEW effective cells: a plan passes the spread and floor of the
    band its design used (``bayes_selection.select_bayes``'s calibration of (p, t, F))."""
    return _band_of_power(power)[0]


def floor_of_power(power: float) -> float:
    """The floor F on the effective cells of the first band whose power, or one of whose powers,
    is ``power`` (BANDS, BAND_POWERS; 0 when none is): what a design of that power uses by default
    (``usage_calibration.calibrate_scene``; ``spread_of_power`` for p = 1)."""
    return _band_of_power(power)[1]


def check_floor(floor) -> float:
    """``floor`` as a float when it is a floor on the effective cells (a finite number >= 0, in
    cells), else ValueError in one line."""
    if (isinstance(floor, bool) or not isinstance(floor, (int, float, np.integer, np.floating))
            or not np.isfinite(floor) or floor < 0):
        raise ValueError(f"usage_design: the floor on the design's effective cells must be a finite number "
                         f">= 0, found {floor!r}")
    return float(floor)


def effective_cells(weights: np.ndarray) -> float:
    """1 / sum w^2 of the weights (n,) normalised to sum 1: how many cells they spread over (n for
    uniform weights, 1 for all on one cell)."""
    w = np.asarray(weights, dtype=np.float64)
    return float(w.sum() ** 2 / np.dot(w, w))


def _spread_weights(log_base: np.ndarray, excess: np.ndarray, spread: float) -> np.ndarray:
    """exp(log_base + t excess) shifted by its largest exponent (the weights up to a factor;
    exp(p^2 v / 2) can span many decades), float64 like log_base."""
    log_w = log_base + spread * excess
    return np.exp(log_w - log_w.max())


def floor_spread(log_base: np.ndarray, excess: np.ndarray, max_spread: float, floor: float,
                 tolerance: float = SPREAD_TOLERANCE) -> float:
    """The largest spread t in [0, max_spread] whose weights exp(log_base + t excess) (normalised)
    keep at least ``floor`` effective cells (``effective_cells``), by bisection on t to
    ``tolerance``: max_spread when its weights keep the floor, 0 when even t = 0's do not (the
    floor is then not met: t = 0 is the design without the spread). Any other t returned meets
    the floor: bisection moves its lower end only to a t that meets it, whether or not the
    effective cells fall monotonically with t (they do in practice).
    log_base: float64 (n_used,) log u + p log g of the cells the scene uses; excess: float64
    (n_used,) p^2 v / 2; floor in cells (``check_floor``); max_spread >= 0."""
    floor = check_floor(floor)
    if not np.isfinite(max_spread) or max_spread < 0:
        raise ValueError(f"usage_design: the largest prior spread must be a finite number >= 0, found {max_spread!r}")
    if floor == 0 or max_spread == 0:
        return float(max_spread)
    if effective_cells(_spread_weights(log_base, excess, max_spread)) >= floor:
        return float(max_spread)
    if effective_cells(_spread_weights(log_base, excess, 0.0)) < floor:
        return 0.0
    low, high = 0.0, float(max_spread)
    while high - low > tolerance:
        mid = 0.5 * (low + high)
        if effective_cells(_spread_weights(log_base, excess, mid)) >= floor:
            low = mid
        else:
            high = mid
    return low


@dataclass(frozen=True)
class ScenePrior:
    """The scene-weighted design problem in the rotated basis.

    dictionary: float32 (n, K) D' = D W Q; weights: float64 (K,) Lambda, the eigenvalues of W M W;
    prior_var: float64 (K,) ones (the rotated prior); usage: float64 (n,) u, sum 1.
    """

    dictionary: np.ndarray
    weights: np.ndarray
    prior_var: np.ndarray
    usage: np.ndarray


def scene_matrix(dictionary, usage: np.ndarray) -> np.ndarray:
    """M = D^T diag(u) D, float64 (K, K), over the rows the scene uses (u > 0) only."""
    rows = np.flatnonzero(usage > 0)
    k = dictionary.shape[1]
    m = np.zeros((k, k))
    for lo in range(0, rows.size, CHUNK_ROWS):
        part = rows[lo:lo + CHUNK_ROWS]
        d = np.asarray(dictionary[part], dtype=np.float64)
        m += d.T @ (d * usage[part, None])
    return 0.5 * (m + m.T)


def is_uniform(usage: np.ndarray) -> bool:
    """True when every cell weighs the same (to float32 rounding): the plain design."""
    return bool(np.ptp(usage) <= 1e-6 * float(np.mean(usage)))


def scene_prior(dictionary, usage: np.ndarray, prior_var: np.ndarray) -> ScenePrior:
    """The rotated problem (module doc) of ``dictionary`` (n, K) float32, ``usage`` (n,) and the
    prior variances (K,)."""
    usage = np.asarray(usage, dtype=np.float64)
    w = np.sqrt(np.asarray(prior_var, dtype=np.float64))
    lam, q = np.linalg.eigh(w[:, None] * scene_matrix(dictionary, usage) * w[None, :])
    lam = np.clip(lam, 0.0, None)  # M is positive semi-definite; rounding can leave -1e-18
    return ScenePrior(rotate(dictionary, w[:, None] * q), lam, np.ones(lam.size), usage)  # D W Q


def rotate(dictionary, rotation: np.ndarray) -> np.ndarray:
    """float32 (n, K): ``dictionary`` (n, K) times the (K, K) ``rotation`` (taken in float32), in
    chunks of CHUNK_ROWS rows (a memory-mapped D is read once)."""
    rotation = np.asarray(rotation).astype(np.float32)
    rotated = np.empty(dictionary.shape, dtype=np.float32)
    for lo in range(0, dictionary.shape[0], CHUNK_ROWS):
        rotated[lo:lo + CHUNK_ROWS] = np.asarray(dictionary[lo:lo + CHUNK_ROWS], dtype=np.float32) @ rotation
    return rotated


def sensitivity(mean, reference, weight, eps: float) -> np.ndarray:
    """float64 (n,) g_c = exp(mu_c) (r_c + eps) / w_c (1/sr): to first order at the mapped values
    ``mean`` (the model's prior mean, or a posterior's level) an error dL_c of the mapped value is
    an error dx_c = g_c dL_c of the BRDF. reference, weight (n,) and eps: the model's map's."""
    mu = np.asarray(mean, dtype=np.float64)
    return np.exp(mu) * (np.asarray(reference, np.float64) + eps) / np.asarray(weight, np.float64)


def linear_usage(usage: np.ndarray, g: np.ndarray, power: float = 2.0, variance=None, spread: float = 0.0,
                 floor: float = 0.0) -> np.ndarray:
    """The usage map for the error of the BRDF itself rather than of its mapped (log) values.

    Arguments: usage (n,) sum 1; g (n,) the cells' ``sensitivity``; ``power``: the exponent of g
    (2: the linear error); ``variance`` (n,) v_c, the prior variance of L_c, and ``spread`` t: the
    weights u g^p exp(t p^2 v / 2) (t = 1: u E[g^p] under the prior; t = 0, the default: g at the
    prior mean); ``floor`` F (cells; 0: none): the t used is the largest in [0, spread] whose
    weights keep F effective cells (``floor_spread``). Returns float64 (n,), sum 1.
    """
    return scene_weights(usage, g, power, variance, spread, floor)[0]


def scene_weights(usage: np.ndarray, g: np.ndarray, power: float, variance=None, spread: float = 0.0,
                  floor: float = 0.0) -> tuple[np.ndarray, float]:
    """(weights float64 (n,) sum 1, the spread t used): ``linear_usage``'s weights u g^p exp(t p^2 v / 2)
    and the t they were made with (``spread`` itself without a floor, else ``floor_spread``'s)."""
    floor = check_floor(floor)
    usage = np.asarray(usage, dtype=np.float64)
    if spread != 0:
        if variance is None:
            raise ValueError("linear_usage: a prior spread needs the cells' prior variance")
        # in logs, shifted by the largest used cell's: exp(p^2 v / 2) can span many decades
        used = usage > 0
        log_base = np.log(usage[used]) + power * np.log(g[used])
        excess = power * power * np.asarray(variance, np.float64)[used] / 2
        if floor > 0:
            spread = floor_spread(log_base, excess, spread, floor)
    if spread == 0:  # g at the prior mean (also when a floor allows no spread: the same weights to the bit)
        out = usage * g ** power
        return out / out.sum(), 0.0
    out = np.zeros(usage.shape)
    out[used] = _spread_weights(log_base, excess, spread)
    return out / out.sum(), float(spread)


def prior_cell_variance(dictionary, prior_var: np.ndarray) -> np.ndarray:
    """float64 (n,): v_c = sum_k D_ck^2 prior_var_k, the prior variance of the mapped value of every
    cell (L = mu + D s, s ~ N(0, diag(prior_var))), in chunks of CHUNK_ROWS rows."""
    prior_var = np.asarray(prior_var, dtype=np.float64)
    out = np.empty(dictionary.shape[0])
    for lo in range(0, dictionary.shape[0], CHUNK_ROWS):
        d = np.asarray(dictionary[lo:lo + CHUNK_ROWS], dtype=np.float64)
        out[lo:lo + CHUNK_ROWS] = (d * d) @ prior_var
    return out


def design_usage(model, usage: np.ndarray, power: float, hedge: float = HEDGE, spread: float = 0.0,
                 floor: float = 0.0, mix: float = 0.0) -> np.ndarray:
    """The weights the scene-aware design minimises the mapped error under (module doc): float64
    (n,) (1 - hedge) / n + hedge u g^power exp(spread power^2 v / 2) / sum, sum 1: the plain
    design's weight (every cell alike) and the scene's, mixed (``linear_usage``; spread t = 0: g at
    the prior mean, 1: the prior's expected g^p). ``usage`` itself when it is uniform (the plain
    design) or when power is 0 and hedge 1; hedge 0 is the uniform map (the plain design).
    ``floor`` F (cells; 0, the default: none): the spread is the largest t in [0, spread] whose
    scene weights keep F effective cells, per scene (``floor_spread``; ``design_spread`` says which).
    ``usage``: (n_valid,) sum 1; ``model``: its mean, reference, weight and eps give g, its
    dictionary and prior variances v. ``mix`` a > 0: mixed with MIX_DESIGN's weights
    (``mixed_weights``)."""
    return design_weights(model, usage, power, hedge, spread, floor, mix=mix)[0]


def design_spread(model, usage: np.ndarray, power: float, spread: float = 0.0, floor: float = 0.0) -> float:
    """The prior spread t ``design_usage`` uses for ``usage`` with these arguments: ``spread`` itself
    without a floor, ``floor_spread``'s with one; 0 for a uniform map or power 0 (no spread)."""
    return design_weights(model, usage, power, 1.0, spread, floor)[1]


def design_weights(model, usage, power, hedge, spread, floor, variance=None,
                   mix: float = 0.0) -> tuple[np.ndarray, float]:
    """(``design_usage``'s weights, the spread t they were made with): what a design needs, and
    what its plan records, from one computation of the weights. variance: a function returning
    the cells' prior variance (``cell_variance_of``, shared by several weights of one model),
    None: computed here when the spread needs it. ``mix`` a > 0: the weights mixed with
    MIX_DESIGN's (``mixed_weights``; the t returned is the scene's own power's)."""
    floor = check_floor(floor)
    usage = np.asarray(usage, dtype=np.float64)
    if is_uniform(usage) or (power == 0 and hedge == 1):
        return usage, 0.0
    if mix:
        return mixed_weights(model, usage, power, hedge, spread, floor, mix, variance)
    if power == 0:
        scene, spread = usage, 0.0
    else:
        v = (variance or cell_variance_of(model))() if spread != 0 else None
        g = sensitivity(model.mean, model.reference, model.weight, model.eps)
        scene, spread = scene_weights(usage, g, power, v, spread, floor)
    return (scene if hedge == 1 else (1.0 - hedge) / usage.size + hedge * scene), spread


def mixed_weights(model, usage, power, hedge, spread, floor, mix, variance=None) -> tuple[np.ndarray, float]:
    """(weights float64 (n,) sum 1, the t of the scene's own part): a w(MIX_DESIGN) + (1 - a) w(power,
    spread, floor), each part ``design_weights``'s (at ``hedge``) normalised to sum 1, a = ``mix`` in
    [0, 1] (the comment at MIX_FEW)."""
    mix = check_share(mix)
    variance = variance or cell_variance_of(model)  # one pass over D for both parts
    p1, t1, f1 = MIX_DESIGN
    mixed_in = design_weights(model, usage, p1, hedge, t1, f1, variance)[0]
    own, used = design_weights(model, usage, power, hedge, spread, floor, variance)
    return mix * mixed_in / mixed_in.sum() + (1.0 - mix) * own / own.sum(), used
