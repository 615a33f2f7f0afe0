"""What a benchmark run does: materials, grid, folds, sample counts, methods and seeds.

One ``BenchConfig`` fully determines the rows of a run (all randomness is derived from
``seed``), whichever machine or executor evaluates the folds.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid
from goniofrost.frost.selectors import SELECTORS

# --quick: every second cell of the MERL grid along each index (1/8 of the cells, the same
# cell edges), so two folds finish in minutes on 2 shared cores.
QUICK_GRID = MerlGrid(45, 45, 90)
# Each selector of frost.selectors.SELECTORS is a method of its name; these run a selector with
# options (the "frost" row uses every training column, the authors' code the first m) or with the
# posterior-mean reconstruction (the gain of the estimator alone): method -> (selector, options,
# reconstructed by the posterior mean).
SELECTOR_METHODS = {"bayes": ("bayes", {}, True), "frost-bayesrec": ("frost", {"y_form": "firstm"}, True),
                    "frost": ("frost", {"y_form": "all"}, False), "frost-firstm": ("frost", {"y_form": "firstm"}, False)}
SELECTOR_METHODS |= {name: (name, {}, selector.posterior) for name, selector in SELECTORS.items()
                     if name not in SELECTOR_METHODS}
# the baselines of bench.baselines, drawn at random (nielsen, random) or laid out (uniform)
BASELINES = ("nielsen", "random", "uniform")
# Method names as they appear in results rows, in report order.
METHODS = (*SELECTOR_METHODS, *BASELINES)
# Result rows of these kinds come with a method (not selectable themselves).
ROW_KINDS = METHODS + ("bayes-target",)
# Distinct integers mixed into the seeds so every method/fold/trial draws its own stream (fixed
# per name, so adding a method never changes another's stream).
METHOD_SEED = {"frost": 0, "frost-firstm": 1, "nielsen": 2, "random": 3, "uniform": 4,
               "bayes": 5, "frost-bayesrec": 6}
SPLIT_SEED = 101


class BenchError(GoniofrostError, ValueError):
    """A benchmark configuration or result that cannot be used."""


@dataclass(frozen=True)
class BenchConfig:
    """Parameters of a cross-validated benchmark run.

    Attributes:
        datasets: dataset specs (``nbrdf:PATH``...) whose materials are pooled.
        grid: the MERL grid every material is tabulated on.
        folds: number of random training/test splits (cross-validation folds).
        n_train, n_test: materials per split (paper: 131 / 20 of 151).
        m_values: sample counts evaluated (sorted, distinct).
        methods: subset of METHODS.
        nielsen_trials: Nielsen runs per fold (each with its own random stream).
        nielsen_subset: random candidate cells per greedy addition (paper: 500).
        nielsen_max_iter: cap on descent iterations after each addition (DESIGN.md: 100).
        random_trials: random selections per fold and m.
        eta: ridge parameter of the reconstruction (paper: 40).
        seed: the one seed of the run.
        target_errors: targets E of the simulated ``capture --target-error`` (with "bayes";
            up to max(m_values) samples, batches as ``frost.stopping``).
    """

    datasets: tuple[str, ...]
    grid: MerlGrid = field(default_factory=MerlGrid)
    folds: int = 10
    n_train: int = 131
    n_test: int = 20
    m_values: tuple[int, ...] = tuple(range(5, 61, 5))
    methods: tuple[str, ...] = METHODS
    nielsen_trials: int = 5
    nielsen_subset: int = 500
    nielsen_max_iter: int = 100
    random_trials: int = 1
    eta: float = 40.0
    seed: int = 0
    target_errors: tuple[float, ...] = (0.05,)

    def __post_init__(self) -> None:
        _check(self)

    def as_dict(self) -> dict:
        """JSON-friendly description of the run."""
        out = asdict(self)
        out["grid"] = self.grid.as_dict()
        return out

    @classmethod
    def quick(cls, datasets, **overrides) -> "BenchConfig":
        """The reduced configuration of ``--quick``: 2 folds, m in {10, 20, 40}, 2 Nielsen trials of
        at most 10 descent iterations per addition, on the 45 x 45 x 90 grid (QUICK_GRID)."""
        base = dict(folds=2, m_values=(10, 20, 40), nielsen_trials=2, nielsen_max_iter=10, grid=QUICK_GRID)
        return cls(tuple(datasets), **(base | overrides))

    def with_(self, **changes) -> "BenchConfig":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


def _check(config: BenchConfig) -> None:
    def bad(name, expected, found):
        raise BenchError(f"benchmark option {name}: expected {expected}, found {found!r}")

    if not config.datasets:
        bad("datasets", "at least one dataset spec", config.datasets)
    for name in ("folds", "n_train", "n_test", "nielsen_trials", "nielsen_subset", "random_trials"):
        if int(getattr(config, name)) < 1:
            bad(name, "a positive integer", getattr(config, name))
    if config.nielsen_max_iter < 0:
        bad("nielsen_max_iter", "an integer >= 0", config.nielsen_max_iter)
    ms = config.m_values
    if not ms or any(int(m) < 1 for m in ms) or list(ms) != sorted(set(ms)):
        bad("m_values", "distinct positive sample counts in increasing order", ms)
    # every fold trains before it selects: a grid of fewer valid cells than the largest m (or than
    # the smallest design of training's noise cross-validation) failed after that, in a worker
    from goniofrost.frost.calibration import M_VALUES

    need, grid = max(max(ms), min(M_VALUES)), config.grid
    if grid.n_valid < need:
        bad("grid", f"at least {need} valid cells (the largest m, and the {min(M_VALUES)} of training's smallest "
                    f"design)", f"{grid.n_th},{grid.n_td},{grid.n_pd} with {grid.n_valid}")
    unknown = [m for m in config.methods if m not in METHODS]
    if unknown or not config.methods:
        bad("methods", f"a non-empty subset of {', '.join(METHODS)}", config.methods)
    if not (np.isfinite(config.eta) and config.eta >= 0):
        bad("eta", "a finite number >= 0", config.eta)
    if any(not (np.isfinite(e) and e > 0) for e in config.target_errors):
        bad("target_errors", "finite numbers > 0", config.target_errors)


def fold_split(n_materials: int, config: BenchConfig, fold: int) -> tuple[np.ndarray, np.ndarray]:
    """Training and test material indices (sorted int64) of one fold.

    Each fold is an independent random split (as in the paper: 10 random 131/20 splits of
    MERL + RGL), drawn from ``seed`` and the fold number only.
    """
    need = config.n_train + config.n_test
    if need > n_materials:
        raise BenchError(
            f"benchmark: {config.n_train} training + {config.n_test} test materials requested "
            f"but the datasets hold only {n_materials}")
    order = np.random.default_rng([config.seed, SPLIT_SEED, fold]).permutation(n_materials)
    return np.sort(order[:config.n_train]), np.sort(order[config.n_train:need])


def method_rng(config: BenchConfig, method: str, fold: int, trial: int) -> np.random.Generator:
    """The random stream of one (method, fold, trial); independent of execution order."""
    return np.random.default_rng([config.seed, METHOD_SEED[method], fold, trial])
