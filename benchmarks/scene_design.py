"""Scene-aware against scene-blind Bayesian design: the error of the rendered scene, and of the whole BRDF.

For each shipped scene (config/scenes) and m, a test material is "measured" at the design's cells
(exact values of the material: the design is what is compared), reconstructed by the posterior
mean, exported as an RGL tensor and rendered by Mitsuba 3 in that scene; the same scene rendered
with the true material (same seed, same spp) is the reference. Reported per scene and m, as the
median over the test materials: the image's relative MSE and PSNR, the scene-seen error (the
log-relative MSE weighted by the scene's usage map: what the plan predicts) and the
whole-BRDF log-relative MSE, for the scene-blind design (``plan``) and the scene-aware one
(``plan --usage``). Test materials are fixed before any result. ``--test-set shared`` (the
default): every 7th material of the combined, sorted shared library (151 materials, MERL and RGL)
starting at the 4th (22 materials); the model is trained on the other 129 only. ``--test-set
builtin`` (issue 29, fixed before its first run): every 3rd of the sorted names of the built-in
analytic library starting at the first (25 of its 74 materials; seven share a name with a shared
MERL material, e.g. ``aluminium``, but are analytic GGX and Lambert lobes, not fits of those
measurements); the model is trained on all 151 shared materials, none of them a test material.
``--test-set builtin1``: the same from the second name (names[1::3], 25 materials; issue 29's second
fresh set, fixed before its first run). ``--test-set builtin2``: names[2::3] (24 materials; the third,
fixed before its first run, issue 29 round 5). ``--test-set fresh1``: 24 seeded analytic materials
of the built-in families (``builtin-random:1:24``), fixed on 2 December 2026 before any run;
``--test-set fresh2``: ``builtin-random:2:24``, the same (round 7, fixed before its first run);
``--test-set fresh3``: ``builtin-random:3:24`` (round 8, fixed before its first run); ``--test-set
fresh4``: ``builtin-random:4:24`` (a confirmation of round 8's design, fixed before its first run);
``--test-set fresh5``: ``builtin-random:5:24`` (round 9, fixed before its first run); ``--test-set
fresh6``: ``builtin-random:6:24`` (round 10, fixed before its first run); ``--test-set fresh7``:
``builtin-random:7:24`` (round 11, fixed before its first run); ``--test-set fresh8``:
``builtin-random:8:24`` (round 12, fixed before its first run); ``--test-set fresh9``:
``builtin-random:9:24`` (a confirmation of round 12's design, fixed before its first run).
``--validation-set seeded`` (issue 29 round 9) chooses instead on 48 seeded analytic materials of the
built-in families (``SEEDED_VALIDATION``: seeds 101 and 102, never a test set) with one model trained
on all 151 shared materials, as the fresh test runs have it: the test sets' distribution, which the
inner folds of MERL and RGL materials never see.

    .venv/bin/python benchmarks/scene_design.py --out /tmp/scene-bench            # full size
    .venv/bin/python benchmarks/scene_design.py --smallest --out /tmp/scene-small  # what the test runs

The scene-aware design's candidates (``CANDIDATES``: the sensitivity power, the hedge and the prior
spread of ``usage_design.design_usage``) are compared first on validation materials only: every
training material held out once in ``--folds`` inner folds, each fold's model trained on the others
(``--only-folds``: some of them, a subset fixed before any result); the rule ``choose_rule`` picks
per m. The test run then compares the shipped design (``select_bayes``'s
defaults for m samples, as ``plan --usage`` picks them: the sensitivity power for m and the scene,
``usage_design.scene_power``) with the blind one, with the earlier u g^0.5 design and with the
design shipped before round 12 (``BEFORE``, ``BEFORE_BANDS``), and with ``--fewer``
also the shipped design at 0.6 m (the goal's fewer-samples branch). Its renders run on Mitsuba's
LLVM variant, on the newest LLVM of the machine (``goniofrost.brdf.drjit_llvm``; the runs in
BENCHMARKS.md@8b3941b named LLVM 19 by hand with DRJIT_LIBLLVM_PATH before that).

    .venv/bin/python benchmarks/scene_design.py \
        --spp 32 --no-export --validation-only --out DIR          # the choice
    ... --spp 32 --no-export --validation-only --validation-set seeded --out DIR   # the choice, seeded materials
    ... --spp 32 --no-export --test-only --fewer --out DIR         # the test run, once
    ... --spp 32 --no-export --test-only --fewer --test-set builtin --out DIR   # issue 29's fresh test set
    ... --spp 32 --no-export --test-only --fewer --test-set builtin1 --out DIR  # its second fresh set
    ... --spp 32 --no-export --test-only --fewer --test-set builtin2 \
        --sequential "seq 5-10-20-40" "seq 4-6-8-10-20-40" --out DIR              # its third, round 5

Prints the tables; writes validation.json and validation-fF.json or validation-seeded.json (every
validation row), results.json (every test row) and, per scene, a picture of the truth and both
reconstructions at the middle m for the first test material.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
SHARED = REPO.parent / "shared" / "data"
SCENES = ("retro-sphere", "grazing-plane", "top-light")
# The built-in test sets: --test-set NAME takes every 3rd of the built-in library's sorted names
# (74) from this offset. "builtin" (offset 0, 25 materials) was issue 29's first fresh set;
# "builtin1" (offset 1, 25 materials) its second, fixed before its first run; "builtin2" (offset 2,
# 24 materials) its third, fixed before its first run (round 5, the sequential design).
BUILTIN_OFFSETS = {"builtin": 0, "builtin1": 1, "builtin2": 2}
# Fresh analytic test sets drawn by seed (``builtin-random:SEED:COUNT``, the built-in families'
# parameter ranges, none a library material): the built-in offsets above are spent. "fresh1" was
# fixed on 2 December 2026 (stop 36) before any run; the model is trained on all 151 shared materials.
# "fresh2" was fixed on 2 December 2026 (issue 29 round 7, branch h/29p) before any run, after the
# validation chose the prior spread. "fresh3" was fixed on 3 December 2026 (issue 29 round 8, branch
# h/29r8) before any run, after the validation chose the floor on the effective cells. "fresh4" was
# fixed on 3 December 2026 (stop 38), before any run, after fresh3 met the goal in 9 of 9 cells: one
# more set, the seed next in line, to confirm the design on materials it has not seen (no choice on it).
# "fresh5" was fixed on 3 December 2026 (issue 29 round 9, branch h/29r9) before any run, after the
# seeded validation (SEEDED_VALIDATION) chose a power per scene from 29 samples.
# "fresh6" was fixed on 3 December 2026 (issue 29 round 10, branch h/29r10) before any run, after the
# seeded validation chose a floor of 6,000 up to 14 samples and the power per scene from 15.
# "fresh7" was fixed on 3 December 2026 (issue 29 round 11, branch h/29r11) before any run, after the
# seeded validation chose a power per scene with 3,300 cells up to 14 samples (p = 1 keeping the floor).
# "fresh8" was fixed on 3 December 2026 (issue 29 round 12, branch h/29r12) before any run, after the
# seeded validation chose the mix of the p = 1 floor design into a scene of p < 1 up to 14 samples.
# "fresh9" was fixed on 3 December 2026 (the session after stop 40) before any run: a confirmation of
# round 12's design, unchanged, on the seed next in line (no choice on it).
FRESH_SETS = {"fresh1": "builtin-random:1:24", "fresh2": "builtin-random:2:24", "fresh3": "builtin-random:3:24",
              "fresh4": "builtin-random:4:24", "fresh5": "builtin-random:5:24", "fresh6": "builtin-random:6:24",
              "fresh7": "builtin-random:7:24", "fresh8": "builtin-random:8:24",
              "fresh9": "builtin-random:9:24"}
# --smallest (a test runs it): the built-in library's first materials, sorted by name, of which every
# model is trained (the seeded validation's too; 74 took 11 s of its 14).
SMALLEST_MATERIALS = 12
# The seeded validation set (``--validation-set seeded``, issue 29 round 9): seeded analytic materials
# of the built-in families, like the fresh test sets, with seeds no test set uses (the test sets'
# seeds are 1 to 9); candidates may be chosen on these.
SEEDED_VALIDATION = ("builtin-random:101:24", "builtin-random:102:24")


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--m", type=int, nargs="+", default=[10, 20, 40])
    p.add_argument("--materials", type=int, default=None, help="use only the first N test materials")
    p.add_argument("--spp", type=int, default=64, help="samples per pixel of the renders")
    p.add_argument("--usage-spp", type=int, default=16, help="samples per pixel of the usage recording")
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--folds", type=int, default=4,
                   help="inner folds of the training materials choosing the design (every one is held out once)")
    p.add_argument("--only-folds", type=int, nargs="+", default=None,
                   help="validate on these inner folds only (of --folds; each fold's model is the same as in the "
                        "full run): a subset fixed before any result, for time")
    p.add_argument("--validation-only", action="store_true", help="stop after choosing the design on validation")
    p.add_argument("--validation-set", choices=("folds", "seeded"), default="folds",
                   help="what the candidates are chosen on: folds (the default): the training materials, each held "
                        "out once in --folds inner folds; seeded: 48 seeded analytic materials of the built-in "
                        "families (builtin-random:101:24 and builtin-random:102:24, seeds no test set uses; with "
                        "--smallest the first of each), one model trained on all the shared materials (151) as "
                        "for the fresh test sets")
    p.add_argument("--test-only", action="store_true", help="the test materials only (the design already chosen)")
    p.add_argument("--fewer", action="store_true",
                   help="also the scene-aware design at 0.6 m (the goal's fewer-samples branch)")
    p.add_argument("--no-export", action="store_true",
                   help="direct renders only (the export-based figure is the slow part: RGL tensors of every reconstruction)")
    p.add_argument("--test-set", choices=("shared",) + tuple(BUILTIN_OFFSETS) + tuple(FRESH_SETS), default="shared",
                   help="shared: 22 of the 151 shared materials, the model trained on the other 129; builtin: 25 of "
                        "the 74 built-in analytic materials (names[0::3]), the model trained on all 151 shared ones; "
                        "builtin1: the same with names[1::3] (issue 29's second fresh set, 25 materials); builtin2: "
                        "names[2::3] (the third, 24 materials); fresh1: 24 seeded analytic materials of the built-in "
                        "families, none a library material (builtin-random:1:24, never run before stop 36); fresh2: "
                        "builtin-random:2:24 (issue 29 round 7, never run before it); fresh3: builtin-random:3:24 "
                        "(issue 29 round 8, never run before it); fresh4: builtin-random:4:24 (round 8's confirmation, never "
                        "run before it); fresh5: builtin-random:5:24 (issue 29 round 9, never run before it); fresh6: "
                        "builtin-random:6:24 (issue 29 round 10, never run before it); fresh7: builtin-random:7:24 (issue 29 round 11, "
                        "never run before it); fresh8: builtin-random:8:24 (issue 29 round 12, never run before it); fresh9: "
                        "builtin-random:9:24 (round 12's confirmation, never run before it)")
    p.add_argument("--sequential", choices=tuple(SEQUENTIAL), nargs="+", default=[],
                   help="also these sequential designs (issue 29 round 5: re-planned at the material's posterior "
                        "mean; per material, direct renders only)")
    p.add_argument("--smallest", action="store_true",
                   help="the built-in library on a 30 x 30 x 60 grid, 1 test material, m = 4, 4 spp (a test runs it)")
    return p.parse_args(argv)


def setting(args):
    """(training dataset specs, test dataset specs, grid, training names, test names, m list, spp,
    usage spp); the two name lists are of different datasets with ``--test-set builtin``."""
    from goniofrost.bench.data import material_names
    from goniofrost.core.grid import FULL_GRID, MerlGrid

    if args.smallest:
        specs, grid, ms, spp, uspp = ["builtin"], MerlGrid(30, 30, 60), [4], 4, 2
        names = sorted(n for _, n in material_names(specs))[:SMALLEST_MATERIALS]
        test = names[3::7][:1]
    else:
        specs = [f"nbrdf:{SHARED / 'nbrdf_merl.npz'}", f"nbrdf:{SHARED / 'nbrdf_rgl.npz'}"]
        grid, ms, spp, uspp = FULL_GRID, args.m, args.spp, args.usage_spp
        names = sorted(n for _, n in material_names(specs))
        test = names[3::7]
    test_specs, training = specs, [n for n in names if n not in test]
    if args.test_set in BUILTIN_OFFSETS and not args.smallest:
        test_specs, training = ["builtin"], names
        test = sorted(n for _, n in material_names(test_specs))[BUILTIN_OFFSETS[args.test_set]::3]
    if args.test_set in FRESH_SETS and not args.smallest:
        test_specs, training = [FRESH_SETS[args.test_set]], names
        test = sorted(n for _, n in material_names(test_specs))
    if args.materials is not None:
        test = test[:args.materials]
    return specs, test_specs, grid, training, test, ms, spp, uspp


def collected(specs, names: list[str]) -> list:
    """The materials of ``specs`` named ``names``, in the order of ``names``. collect_materials
    returns the datasets' own order (MERL before RGL, the built-in library's), not the sorted
    names the benchmark labels its rows with: without the reordering every row's name is another
    material's (the medians and paired ratios are the same, the labels and pictures' names not)."""
    from goniofrost.datasets.tabulate import collect_materials

    by_name = {m.name: m for m in collect_materials(specs, only=names)}
    return [by_name[n] for n in names]


def image_errors(image: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(relative MSE, PSNR in dB against the truth's peak) of two (H, W, 3) renders."""
    err = float(np.mean((image - truth) ** 2))
    rel = err / float(np.mean(truth ** 2))
    peak = float(np.max(truth))
    return rel, 10.0 * np.log10(peak * peak / err) if err > 0 else float("inf")


# The candidate designs, chosen among on the validation materials before the test materials are
# looked at: name -> (p, a, t, F), the design's weights (1 - a) / n + a u g^p exp(t p^2 v / 2) / sum
# (``usage_design.design_usage``): each cell's use u weighted by the image's sensitivity g to its
# mapped value to the power p, with t = 1 its expectation under the prior (v: the prior variance of
# the cell's mapped value), mixed with the plain design's weight (the whole BRDF alike) with the
# scene's share a. p None: the power for m (``usage_design.sensitivity_power``, a design per m).
# F: a floor on the weights' effective cells 1 / sum w^2 (``usage_design.floor_spread``; 0: none):
# t is then the most the spread may be, and each scene's t the largest in [0, t] keeping F. t or F
# None: select_bayes's default for m (the band's). p a tuple of powers: a power per scene, the largest
# of the tuple whose weights (at t, no floor on t) keep F effective cells, the smallest when none
# does (``scene_power``; F is then the power's floor, not the spread's).
# Round 8 (issue 29): the shipped design against the floor at p = 1 (validated at m <= 14 only; F
# fixed before any result from round 7's effective cells, BENCHMARKS.md@8b3941b "Issue 29, round 8").
# "shipped" is the design shipped before round 8 (t = 0 at m <= 14), kept under the name it was
# validated with; F = 3,000 won and is now usage_design's default up to 14 samples. The
# candidates of round 7 ("prior p-by-m", "prior p0.5", "prior p0.25": t = 1, no floor) and the hedge
# candidates of round 3 ("g^0.5 a0.9" ... "g^1 a0.7") are in those rounds' sections of BENCHMARKS.md@8b3941b.
# Round 9 (issue 29, chosen on ``--validation-set seeded`` at m = 40 for the band from 29 samples,
# m = 20 reported; BENCHMARKS.md@8b3941b "Issue 29, round 9"; fixed before any result in
# /work/scratch29r9/DECISION.txt): the shipped bands (select_bayes's defaults), a power per scene by
# the effective cells of its weights at t = 1 (F = 4,000 and 8,000: on the model of all 151 shared
# materials, 4,000 gives the retro sphere 0.75, the grazing plane 0.5 and the top light 1; 8,000 the
# top light 0.75), round 8's p = 1 with the floor (F = 3,000) and the shipped bands hedged (a = 0.7).
# Round 8's candidates ("floor 1500" ... "floor 6000" at m <= 14) are in its section.
# Round 9's table is in its section ("p-cells 8000", "p1 floor 3000", "hedge 0.7" besides these two).
# Round 10 (issue 29, ``--validation-set seeded``, ``--m 6 10 20``; fixed before any result in
# /work/scratch29r10/DECISION.txt): the band up to 14 samples chosen at m = 10 among the shipped p = 1
# with the floor 3,000 and three designs aimed at the grazing plane (fresh5's miss at m = 10): a power
# per scene with 3,000 cells (on the 151-material model only the grazing plane changes, to 0.75),
# with 4,000 (round 9's rule: retro sphere 0.75, grazing plane 0.5, top light 1) and p = 1 with a
# floor of 6,000; the band 15-28 chosen at m = 20 between the shipped p = 0.25 and the power per
# scene with 4,000 cells (CHOOSE_AMONG); m = 6 is reported only.
# Round 10's candidates ("p-cells 3000", "p-cells 4000", "floor 6000") are in its section.
# Round 11 (issue 29, ``--validation-set seeded``, ``--m 6 10``; fixed before any result in
# /work/scratch29r11/DECISION.txt): the band up to 14 samples chosen at m = 10 between the shipped
# design (p = 1, t up to 1, F = 6,000) and a power per scene with 3,300 cells whose p = 1 scenes keep
# the shipped floor: F a pair (cells, floor), the power chosen at t = 1 without a floor by the first,
# the second the floor on t when the scene's power is the tuple's largest (the floor belongs to p = 1).
# On the 151-material model 3,300 lies between the grazing plane's 3,063 cells at p = 0.75 and the
# retro sphere's 3,553 at p = 1: the grazing plane takes p = 0.5 (t = 1), the retro sphere and top
# light p = 1 with the floor (the shipped design there). m = 6 is reported only.
# Round 11's candidate "p-cells 3300 + floor" (won; now select_bayes's default) is in its section.
# Round 12 (issue 29, ``--validation-set seeded``, ``--m 6 10``; fixed before any result in
# /work/scratch29r12/DECISION.txt): the band up to 14 samples chosen at m = 10 between the shipped
# design of round 11 without a mix ("shipped") and "mix 1 + p": a scene whose power (round 11's rule)
# is below 1 weighs 0.5 w(p = 1, t up to 1, F = 6,000) + 0.5 w(its p, t = 1), each part summing to 1
# (``usage_design.mixed_weights``; CANDIDATE_MIX: select_bayes's mix share, 0 none), scenes of p = 1
# unchanged. On the 151-material model only the grazing plane (p = 0.5) differs. m = 6 is reported only.
# Round 12's candidate "mix 1 + p" (won; now select_bayes's default) is in its section.
# Round 13 (issue 29, ``--validation-set seeded``, ``--m 6 10``, ``--scenes grazing-plane``; fixed
# before any result in /work/scratch29r13/DECISION.txt): the band up to 14 samples chosen at m = 10
# between the shipped design of round 12 ("shipped": a scene of p < 1 weighs 0.5 w(p = 1 floor
# design) + 0.5 w(its p, t = 1)) and "mix 1 + p@t0": the same mix with its own part at t = 0 (g at
# the prior mean; CANDIDATE_MIX_SPREAD: select_bayes's mix_spread). The candidate was suggested by a
# test set (fresh8's run, where the u g^0.5 design at t = 0 reached -85 % at the grazing plane at
# m = 10), so it is chosen on validation only and tested on a new set. Scenes of p = 1 unchanged: on
# the 151-material model only the grazing plane (p = 0.5) differs. m = 6 is reported only. "shipped"
# won at step (a) (the candidate's grazing-plane fabrics 1.26 of blind); nothing changed.
CANDIDATES = {"shipped": (None, 1.0, None, None), "mix 1 + p@t0": (None, 1.0, None, None)}
# The share of usage_design.MIX_DESIGN's weights select_bayes mixes into each candidate's design
# (its ``mix``; a candidate not here: the default, BAND_MIX).
CANDIDATE_MIX = {"mix 1 + p@t0": 0.5}
# The prior spread of a mixed design's own part (select_bayes's ``mix_spread``; a candidate not
# here: the default, usage_design.mix_spread).
CANDIDATE_MIX_SPREAD = {"mix 1 + p@t0": 0.0}
# Per m, the candidates ``choose_rule`` chooses among (the band's own; an m not here chooses among
# every candidate, and the round's section says which m decide).
CHOOSE_AMONG = {10: ("shipped", "mix 1 + p@t0")}
# Round 11's rule (``choose_rule``): a candidate with a (scene, family) median ratio to blind above 1,
# over the families with at least FAMILY_MIN validation materials, is discarded when another
# candidate has none (the worst-scene median hid the grazing plane's fabrics at 8.9x blind in round 10).
FAMILY_MIN = 4
# Round 12's step (b) (``choose_rule``, ``worse_scenes``): the scenes' median ratios sorted from worst
# down, compared in turn; two within TIE_TOLERANCE (relative, of the larger) tie and the next decides.
TIE_TOLERANCE = 0.005
# The earlier u g^0.5 design the test run renders beside the shipped one.
BESIDE = {"g^0.5": (0.5, 1.0, 0.0, 0.0)}
# The key of the shipped design before round 12 (round 11's), which the test run renders beside the
# shipped one (at m and at 0.6 m): up to 14 samples select_bayes's default without the mix (a power
# per scene, p = 1 with the floor of 6,000 effective cells, p < 1 t = 1 unmixed; BEFORE_BANDS: the
# last m of the band, the SceneDesign fields); from 15 the same design as shipped
# (rendered once). (Round 11's "before (round 10)", round 10's "before (round 9)", round 9's "before
# (round 8)", round 8's "before (round 7)" and round 7's "t0 (before)" are in those rounds' sections
# of BENCHMARKS.md@8b3941b.)
BEFORE = "before (round 11)"
BEFORE_BANDS = ((14, {"mix": 0.0}),)


def candidate_power(model, usage: np.ndarray, powers, hedge: float, spread: float, cells) -> tuple[float, float]:
    """(p, F) of a candidate with a power per scene (a tuple p of CANDIDATES): p the largest of
    ``powers`` whose weights at ``spread`` (no floor) keep ``cells`` effective cells (``scene_power``);
    ``cells`` a pair (cells, floor): F the floor when p is the largest of ``powers``, else 0; a number:
    F = 0 (no floor on t)."""
    cells, floor = cells if isinstance(cells, tuple) else (cells, 0.0)
    p = scene_power(model, usage, powers, hedge, spread, cells)
    return p, (floor if p == max(powers) else 0.0)


def scene_power(model, usage: np.ndarray, powers, hedge: float, spread: float, floor: float) -> float:
    """The largest power of ``powers`` whose design weights for ``usage`` (at ``spread``, no floor on
    it) keep at least ``floor`` effective cells; the smallest when none does (CANDIDATES; the
    product's rule, ``usage_design.largest_power``)."""
    from goniofrost.frost.usage_design import largest_power

    return largest_power(model, usage, powers, floor, spread, 0.0, hedge)


def scene_designs(model, usage: dict, ms, candidates=CANDIDATES) -> dict:
    """{m: {"blind": rows, (scene, name): rows}} for every m of ``ms``: the plain design, and per
    scene the design of every candidate (p, a, t, F) of ``candidates`` (see CANDIDATES); the designs
    of a fixed p (or a p per scene) are nested (one of max(ms) picks, read at every m), p None is
    designed per m."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign

    m_max = max(ms)
    blind = select_bayes(model, m_max).positions
    designs = {m: {"blind": blind} for m in ms}
    for s, u in usage.items():
        for name, (p, a, t, f) in candidates.items():
            if isinstance(p, tuple):
                p, f = candidate_power(model, u, p, a, t, f)
            options = candidate_options(name, p, a, t, f)
            if p is None:
                for m in ms:
                    designs[m][(s, name)] = select_bayes(model, m, scene=SceneDesign(u, **options)).positions
            else:
                rows = select_bayes(model, m_max, scene=SceneDesign(u, **options)).positions
                for m in ms:
                    designs[m][(s, name)] = rows
    return designs


def candidate_options(name: str, p, a: float, t, f) -> dict:
    """The SceneDesign fields (besides usage) of the candidate ``name`` (CANDIDATES: hedge a, spread t and
    floor F, None the defaults) with its power p resolved (a number, or None for the shipped rule's,
    which alone takes the candidate's mix, CANDIDATE_MIX and CANDIDATE_MIX_SPREAD)."""
    if p is None:
        return {"hedge": a, "prior_spread": t, "spread_floor": f, "mix": CANDIDATE_MIX.get(name),
                "mix_spread": CANDIDATE_MIX_SPREAD.get(name)}
    return {"hedge": a, "prior_spread": t, "spread_floor": f, "sensitivity_power": p}


def candidate_spreads(model, usage: dict, m: int, candidates=CANDIDATES) -> dict:
    """{scene: {name: [p, t, effective cells]}}: the power and prior spread each candidate's design of
    m samples uses for each scene (the floor's t, ``usage_design.design_weights``; a tuple's p,
    ``scene_power``) and its weights' effective cells 1 / sum w^2 (``usage_design.effective_cells``);
    the rest as ``scene_designs`` asks select_bayes for it (``bayes_selection.design_options``: p None
    the shipped rule's power for the scene, t or F None the defaults for m)."""
    from goniofrost.frost.bayes_selection import design_options
    from goniofrost.frost.usage_design import SceneDesign, design_weights, effective_cells

    out = {}
    for s, u in usage.items():
        out[s] = {}
        for name, (p, a, t, f) in candidates.items():
            if isinstance(p, tuple):
                p, f = candidate_power(model, u, p, a, t, f)
            options = candidate_options(name, p, a, t, f)
            choice = design_options(model, SceneDesign(u, **options), m)
            weights, used = design_weights(model, u, choice.power, options["hedge"], choice.spread, choice.floor,
                                           mix=choice.mix)
            out[s][name] = [choice.power, used, effective_cells(weights)]
    return out


# The sequential scene-aware designs (issue 29, round 5; ``frost.sequential_design``): name ->
# (stages, power). The first stages[0] picks are the shipped design's of stages[1] samples; at each
# later stage end the design re-plans from the picks so far, with g at this material's posterior
# mean (the benchmark "measures" the material exactly), to that many picks. "half": per m, m // 2
# then m; the others are nested (one chain to 40, read at every m). power None: the power for the
# stage's end (``usage_design.sensitivity_power``).
SEQUENTIAL = {"seq half": ("half", None), "seq 5-10-20-40": ((5, 10, 20, 40), None),
              "seq 5-10-20-40 p1": ((5, 10, 20, 40), 1.0), "seq 4-6-8-10-20-40": ((4, 6, 8, 10, 20, 40), None)}


def sequential_picks(model, usage: np.ndarray, truth: np.ndarray, stages, power=None, shipped=None) -> np.ndarray:
    """The rows of a sequential design (SEQUENTIAL) of stages[-1] picks on the material ``truth``
    (n_valid, 3); ``shipped``: an optional {m: rows} cache of the shipped designs (the same for
    every material)."""
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.usage_design import SceneDesign
    from goniofrost.frost.sequential_design import continue_design

    shipped = {} if shipped is None else shipped
    if stages[1] not in shipped:
        shipped[stages[1]] = select_bayes(model, stages[1], scene=SceneDesign(usage)).positions
    picked = shipped[stages[1]][:stages[0]]
    for end in stages[1:]:
        more = continue_design(model, usage, picked, model.to_log(truth[picked], picked), end, power).rows
        picked = np.concatenate([picked, more])
    return picked


def sequential_designs(model, usage: dict, truth: np.ndarray, ms, names, shipped: dict) -> dict:
    """{m: {(scene, name): rows}} of the SEQUENTIAL designs ``names`` on one material, every m of ms;
    ``shipped``: {scene: {m: rows}} caches of the shipped designs."""
    out = {m: {} for m in ms}
    for s, u in usage.items():
        for name in names:
            stages, power = SEQUENTIAL[name]
            if stages == "half":
                for m in ms:
                    out[m][(s, name)] = sequential_picks(model, u, truth, (m // 2, m), power, shipped.setdefault(s, {}))
            else:
                chain = sequential_picks(model, u, truth, stages, power, shipped.setdefault(s, {}))
                for m in ms:
                    out[m][(s, name)] = chain[:m]
    return out


def direct_rows(model, designs, truths, names, ms, direct, usage, grid, spp, extra=None, metrics=True, own=None):
    """Rows of the direct renders (``mitsuba_tabulated``: the same paths for every BRDF) of every
    material, scene, m and design; ``designs``: {key: rows} (every m) or {m: {key: rows}} (the
    designs evaluated at m); ``extra(k, name, truth)`` may add rows of its own (export renders)
    and is called once per material; ``usage``: {scene: map}; ``metrics``: also the whole-BRDF and
    seen errors (two passes over the grid per reconstruction); ``own(truth)``: optional designs of
    this material alone, {m: {key: rows}} (the sequential ones). Returns (rows, pictures of the first material)."""
    from goniofrost.frost.metrics import log_relative_mse
    from goniofrost.frost.reconstruction import reconstruct_bayes

    weight = np.asarray(model.weight, dtype=np.float64)[:, None]
    rows, pictures = [], {}
    for k, name in enumerate(names):
        truth = np.asarray(truths[k], dtype=np.float64)
        reference = {s: scene.render(grid, truth, spp) for s, scene in direct.items()}
        mine = own(truth) if own is not None else {}
        done = {}  # (scene, picked cells) -> the row's numbers: designs that pick the same cells render once
        for m in ms:
            for key, picked in {**(designs[m] if m in designs else designs), **mine.get(m, {})}.items():
                cells = np.asarray(picked[:m]).tobytes()
                scenes = [s for s in direct if key == "blind" or key[0] == s]
                rec = None
                if any((s, cells) not in done for s in scenes):
                    rec = reconstruct_bayes(model, picked[:m], truth[picked[:m]], with_std=False).brdf
                    if metrics:
                        diff = (np.log(weight * truth + model.eps) - np.log(weight * np.maximum(rec, 0) + model.eps)) ** 2
                for s in scenes:
                    if (s, cells) not in done:
                        image = direct[s].render(grid, rec, spp)
                        rel, psnr = image_errors(image, reference[s])
                        done[(s, cells)] = {"image_rel_mse": rel, "psnr_db": psnr}
                        if metrics:
                            done[(s, cells)].update(brdf_log_mse=log_relative_mse(model, truth, rec),
                                                    seen_log_mse=float(usage[s] @ diff.mean(1)))
                        if k == 0 and m == ms[len(ms) // 2]:
                            done[(s, cells)]["image"] = image
                    rows.append({"material": name, "scene": s, "m": m, "design": "blind" if key == "blind" else key[1],
                                 "render": "direct", **{f: v for f, v in done[(s, cells)].items() if f != "image"}})
                    if k == 0 and m == ms[len(ms) // 2]:
                        pictures[(s, rows[-1]["design"])] = done[(s, cells)]["image"]
                        pictures[(s, "truth")] = reference[s]
        if extra is not None:
            rows.extend(extra(k, name, truth))
    return rows, pictures


def medians(rows: list[dict], key="image_rel_mse") -> dict:
    """{(scene, m, design, render): median of ``key`` over the materials}."""
    groups: dict = {}
    for r in rows:
        groups.setdefault((r["scene"], r["m"], r["design"], r["render"]), []).append(r[key])
    return {g: float(np.median(v)) for g, v in groups.items()}


def choose_rule(rows: list[dict], ms: list[int], extra: dict | None = None) -> tuple[dict, dict]:
    """Per m, the candidate (of CHOOSE_AMONG[m], else CANDIDATES) whose scenes are best: (round 11) a
    candidate with a (scene, family) median ratio above 1 (``family_ratios``, families of FAMILY_MIN
    materials or more) is left out when another candidate has none; then (round 12) each candidate's
    per-scene ratios of its median direct-render image error to the blind design's (the goal's
    measure, per cell), sorted from worst down, compared worst first, ties within TIE_TOLERANCE
    broken by the next worst (``worse_scenes``); full ties to the earlier candidate. ``extra``:
    {(m, name): [ratios]} of scenes not rendered in ``rows`` (the same design for every candidate,
    from an earlier run). Fixed before the test run and applied to the validation rows only.
    Returns ({m: name}, {(m, name): the worst ratio})."""
    med = medians(rows)
    scenes = sorted({s for s, _, _, _ in med})
    ratios = {(m, w): sorted([med[(s, m, w, "direct")] / med[(s, m, "blind", "direct")] for s in scenes]
                             + list((extra or {}).get((m, w), [])), reverse=True)
              for m in ms for w in CANDIDATES}
    choice = {}
    for m in ms:
        among = CHOOSE_AMONG.get(m, tuple(CANDIDATES))
        clean = [w for w in among if max(family_ratios(rows, m, w).values(), default=0.0) <= 1.0] or list(among)
        best = clean[0]
        for w in clean[1:]:
            if worse_scenes(ratios[(m, best)], ratios[(m, w)]):
                best = w
        choice[m] = best
    return choice, {k: v[0] for k, v in ratios.items()}


def worse_scenes(a: list[float], b: list[float], tolerance: float = TIE_TOLERANCE) -> bool:
    """True when scene ratios ``a`` (sorted from worst down) are worse than ``b``: at the first place
    where the two differ by more than ``tolerance`` of the larger, a's is the larger; False on a tie."""
    for x, y in zip(a, b):
        if abs(x - y) > tolerance * max(x, y):
            return x > y
    return False


def family(name: str) -> str | None:
    """The built-in family of a seeded analytic material (``r{seed}-{index}-{family}``), else None."""
    parts = name.split("-", 2)
    return parts[2] if len(parts) == 3 and parts[0][:1] == "r" and parts[1].isdigit() else None


def family_ratios(rows: list[dict], m: int, design: str, least: int = FAMILY_MIN) -> dict:
    """{(scene, family): median over the family's materials of the design's direct-render image
    error / the blind design's at m}, for the families with at least ``least`` materials."""
    by: dict = {}
    for r in rows:
        if r["m"] == m and r["render"] == "direct" and r["design"] in ("blind", design) and family(r["material"]):
            by.setdefault((r["scene"], family(r["material"]), r["material"]), {})[r["design"]] = r["image_rel_mse"]
    groups: dict = {}
    for (s, fam, _), v in by.items():
        if len(v) == 2:
            groups.setdefault((s, fam), []).append(v[design] / v["blind"])
    return {k: float(np.median(v)) for k, v in groups.items() if len(v) >= least}


def family_table(rows: list[dict], ms: list[int]) -> str:
    """Per scene, m and family (of any size, its count beside it): each candidate's median ratio to blind."""
    lines = ["| scene | m | family (n) | " + " | ".join(CANDIDATES) + " |", "|---|---|---|" + "---|" * len(CANDIDATES)]
    for m in ms:
        ratios = {w: family_ratios(rows, m, w, least=1) for w in CANDIDATES}
        counts: dict = {}
        for r in rows:
            if r["m"] == m and r["design"] == "blind" and r["render"] == "direct" and family(r["material"]):
                counts[(r["scene"], family(r["material"]))] = counts.get((r["scene"], family(r["material"])), 0) + 1
        for s in SCENES:
            for fam in sorted({f for (s2, f) in counts if s2 == s}):
                lines.append(f"| {s} | {m} | {fam} ({counts[(s, fam)]}) | "
                             + " | ".join(f"{ratios[w].get((s, fam), float('nan')):.2f}" for w in CANDIDATES) + " |")
    return "\n".join(lines)


def validation(specs, grid, training: list[str], folds: int, usage, direct, ms, spp, t0, out: Path,
               only=None) -> list[dict]:
    """The candidates' direct-render rows on every training material, each held out of a model
    trained on the others of ``training`` in ``folds`` inner folds (fold f: training[f::folds]);
    the test materials never enter. ``only``: these folds alone (default all). Each fold's rows
    are written to out/validation-fF.json."""
    from goniofrost.datasets.tabulate import tabulate_materials
    from goniofrost.frost.training import train

    rows = []
    for f in (range(folds) if only is None else only):
        held = training[f::folds]
        inner = train(specs, only=[n for n in training if n not in held], grid=grid, cache=True)
        designs = scene_designs(inner, usage, ms)
        spreads = candidate_spreads(inner, usage, max(ms))
        print(f"fold {f + 1}/{folds}: {len(held)} validation materials, model of {len(training) - len(held)} "
              f"({time.perf_counter() - t0:.0f} s); {spreads_line(spreads, max(ms))}", flush=True)
        fold_rows, _ = direct_rows(inner, designs, tabulate_materials(collected(specs, held), grid), held,
                                   ms, direct, usage, grid, spp, extra=progress_only(t0, len(held)), metrics=False)
        (out / f"validation-f{f}.json").write_text(json.dumps({"held": held, "spreads": spreads, "rows": fold_rows}))
        rows += fold_rows
        del inner
    return rows


def spreads_line(spreads: dict, m: int) -> str:
    """The progress line's part on each scene's candidates: {scene: {candidate: (p, t, effective cells)}}."""
    return (f"at m = {m} each scene's (p, t, effective cells): "
            + "; ".join(f"{s} " + ", ".join(f"{w} ({p:.2f}, {t:.2f}, {n:,.0f})" for w, (p, t, n) in d.items())
                        for s, d in spreads.items()))


def seeded_validation(specs, grid, usage, direct, ms, spp, t0, out: Path, smallest=False) -> list[dict]:
    """The candidates' direct-render rows on the SEEDED_VALIDATION materials (the first of each with
    ``smallest``), the model trained on every material of ``specs`` (none of them is seeded; with
    ``smallest`` the SMALLEST_MATERIALS first, as the other paths' models); the rows are written to
    out/validation-seeded.json."""
    from goniofrost.bench.data import material_names
    from goniofrost.datasets.tabulate import tabulate_materials
    from goniofrost.frost.training import train

    seeded = list(SEEDED_VALIDATION)
    held = [n for spec in seeded for n in sorted(n for _, n in material_names([spec]))[:1 if smallest else None]]
    names = sorted(n for _, n in material_names(specs))[:SMALLEST_MATERIALS if smallest else None]
    model = train(specs, only=names, grid=grid, cache=True)
    designs = scene_designs(model, usage, ms)
    spreads = candidate_spreads(model, usage, max(ms))
    print(f"seeded validation: {len(held)} materials ({', '.join(seeded)}), model of {len(names)} "
          f"({time.perf_counter() - t0:.0f} s); {spreads_line(spreads, max(ms))}", flush=True)
    rows, _ = direct_rows(model, designs, tabulate_materials(collected(seeded, held), grid), held, ms, direct,
                          usage, grid, spp, extra=progress_only(t0, len(held)), metrics=False)
    (out / "validation-seeded.json").write_text(json.dumps({"held": held, "sets": seeded, "spreads": spreads,
                                                            "rows": rows}))
    return rows


def main(argv=None) -> int:
    from goniofrost.brdf.mitsuba_tabulated import TabulatedScene
    from goniofrost.brdf.mitsuba_usage import record_usage
    from goniofrost.datasets.tabulate import tabulate_materials
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.training import train
    from goniofrost.frost.usage_design import SceneDesign

    args = parse(argv)
    specs, test_specs, grid, training, test, ms, spp, uspp = setting(args)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    scenes = {s: REPO / "config" / "scenes" / f"{s}.xml" for s in args.scenes}
    usage = {s: record_usage(path, "sample", spp=uspp, grid=grid)[0] for s, path in scenes.items()}
    direct = {s: TabulatedScene(path, "sample") for s, path in scenes.items()}
    # 1. the rule, chosen on training materials only (inner folds)
    if not args.test_only:
        if args.validation_set == "seeded":
            v_rows = seeded_validation(specs, grid, usage, direct, ms, spp, t0, args.out, args.smallest)
        else:
            v_rows = validation(specs, grid, training, 2 if args.smallest else args.folds, usage, direct, ms, spp, t0,
                                args.out, args.only_folds)
        choice, scores = choose_rule(v_rows, ms)
        print(f"chosen on {len({r['material'] for r in v_rows})} validation materials: {choice} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        print(validation_table(v_rows, ms))
        print(family_table(v_rows, ms))
        (args.out / "validation.json").write_text(json.dumps(
            {"choice": {str(m): c for m, c in choice.items()},
             "scores": {f"{m} {w}": v for (m, w), v in scores.items()}, "rows": v_rows}, indent=1))
        if args.validation_only:
            return 0
    # 2. the test materials, the model trained on every other material; the shipped rule
    # (select_bayes's defaults for m samples, as plan --usage picks them) against the blind design
    # and the rule before the hedge (g^0.5, nested)
    model = train(specs, only=training, grid=grid, cache=True)
    print(f"model: {len(training)} training materials, K = {model.n_components} ({time.perf_counter() - t0:.0f} s); "
          f"{len(test)} test materials ({args.test_set}): {', '.join(test)}", flush=True)
    designs = scene_designs(model, usage, ms, BESIDE)
    for m in ms:
        designs[m].update({(s, "aware"): select_bayes(model, m, scene=SceneDesign(u)).positions
                           for s, u in usage.items()})
    fewer = sorted({round(0.6 * m) for m in ms} - set(ms)) if args.fewer else []
    designs.update({m: {(s, "aware"): select_bayes(model, m, scene=SceneDesign(u)).positions for s, u in usage.items()}
                    for m in fewer})
    # the shipped design before round 12 beside it, at m and 0.6 m (BEFORE_BANDS; the same design
    # from 29 samples: rendered once)
    for m in ms + fewer:
        before = next((d for last, d in BEFORE_BANDS if m <= last), None)
        designs[m].update({(s, BEFORE): designs[m][(s, "aware")] if before is None else
                           select_bayes(model, m, scene=SceneDesign(u, **before)).positions
                           for s, u in usage.items()})
    truths = tabulate_materials(collected(test_specs, test), grid)
    own, shipped = None, {s: {m: designs[m][(s, "aware")] for m in designs} for s in usage}
    if args.sequential:
        def own(truth):
            return sequential_designs(model, usage, truth, sorted(ms + fewer), args.sequential, shipped)
    with tempfile.TemporaryDirectory() as tmp:
        exported = (progress_only(t0, len(test)) if args.no_export else
                    export_renders(model, designs, "aware", scenes, ms, grid, spp, Path(tmp), t0, len(test)))
        rows, pictures = direct_rows(model, designs, truths, test, sorted(ms + fewer), direct, usage, grid, spp,
                                     extra=exported, own=own)
    (args.out / "results.json").write_text(json.dumps({
        "test_set": args.test_set, "sequential": args.sequential, "test": test, "spp": spp, "usage_spp": uspp, "m": ms, "fewer": fewer, "grid": grid.as_dict(), "rows": rows},
        indent=1))
    print(table(rows, ms, "aware", "g^0.5"))
    print(goal_table(rows, ms, "aware"))
    print(goal_lines(rows, ms, "aware"))
    # the shipped design against the one before round 9 (export columns: not rendered)
    print(table(rows, ms, "aware", BEFORE))
    print(goal_table(rows, ms, BEFORE))
    for name in args.sequential:  # each sequential design beside the shipped one (export columns: not rendered)
        print(table(rows, ms, name, "aware"))
        print(goal_table(rows, ms, name))
    save_pictures(pictures, args.out, "aware")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


def progress_only(t0, n_test):
    """The per-material callback of ``direct_rows`` without export renders: a progress line."""
    def rows_of(k, name, _truth):
        print(f"{k + 1}/{n_test} {name} ({time.perf_counter() - t0:.0f} s)", flush=True)
        return []

    return rows_of


def export_renders(model, designs, choice, scenes, ms, grid, spp, tmp: Path, t0, n_test):
    """The export-based figure: truth and reconstructions (blind, and the chosen weighting) as RGL
    tensors, rendered by Mitsuba's ``measured`` BSDF. Returns the per-material callback of
    ``direct_rows``."""
    from goniofrost.brdf.mitsuba_export import export_mitsuba
    from goniofrost.brdf.mitsuba_usage import render_with_bsdf
    from goniofrost.frost.reconstruction import reconstruct_bayes

    def rows_of(k, name, truth):
        full = np.full((grid.size, 3), np.nan)
        full[grid.valid_cells] = truth
        export_mitsuba(tmp / "truth.bsdf", full, grid, source=name)
        reference = {s: render_with_bsdf(path, "sample", tmp / "truth.bsdf", spp) for s, path in scenes.items()}
        out = []
        for m in ms:
            for key, picked in designs[m].items():
                if key != "blind" and key[1] != choice:
                    continue
                full[grid.valid_cells] = reconstruct_bayes(model, picked[:m], truth[picked[:m]], with_std=False).brdf
                export_mitsuba(tmp / "rec.bsdf", full, grid, source=f"{name} {key} m={m}")
                for s, path in scenes.items():
                    if key != "blind" and key[0] != s:
                        continue
                    rel, psnr = image_errors(render_with_bsdf(path, "sample", tmp / "rec.bsdf", spp), reference[s])
                    out.append({"material": name, "scene": s, "m": m, "design": "blind" if key == "blind" else key[1],
                                "render": "export", "image_rel_mse": rel, "psnr_db": psnr})
        print(f"{k + 1}/{n_test} {name} ({time.perf_counter() - t0:.0f} s)", flush=True)
        return out

    return rows_of


def paired(rows: list[dict], scene: str, m: int, design: str) -> tuple[float, int, int]:
    """(median over materials of aware / blind image error, materials where the design is better,
    materials) of the direct renders of ``scene`` at m."""
    by = {}
    for r in rows:
        if r["scene"] == scene and r["m"] == m and r["render"] == "direct" and r["design"] in ("blind", design):
            by.setdefault(r["material"], {})[r["design"]] = r["image_rel_mse"]
    ratio = np.array([v[design] / v["blind"] for v in by.values() if len(v) == 2])
    return float(np.median(ratio)), int(np.sum(ratio < 1)), ratio.size


def validation_table(rows: list[dict], ms: list[int]) -> str:
    """Per scene and m: each candidate's median direct-render image error / the blind design's
    (the goal's measure) and the share of materials it is better for; the worst scene per m."""
    med = medians(rows)
    lines = ["| scene | m | " + " | ".join(CANDIDATES) + " |", "|---|---|" + "---|" * len(CANDIDATES)]
    for s in SCENES:
        for m in ms:
            if (s, m, "blind", "direct") in med:
                lines.append(f"| {s} | {m} | " + " | ".join(
                    f"{med[(s, m, w, 'direct')] / med[(s, m, 'blind', 'direct')]:.2f} ({paired(rows, s, m, w)[1]}"
                    f"/{paired(rows, s, m, w)[2]})" for w in CANDIDATES) + " |")
    for m in ms:
        worst = [max(med[(s, m, w, "direct")] / med[(s, m, "blind", "direct")] for s in SCENES
                     if (s, m, "blind", "direct") in med) for w in CANDIDATES]
        lines.append(f"| worst scene | {m} | " + " | ".join(f"{v:.2f}" for v in worst) + " |")
    return "\n".join(lines)


def table(rows: list[dict], ms: list[int], choice: str, other: str) -> str:
    """Median over materials per scene and m: image rel. MSE of both renders (direct: the same
    paths for every BRDF; export: RGL tensors), the other weighting's, and the whole-BRDF error."""
    med, brdf, seen = medians(rows), medians([r for r in rows if r["render"] == "direct"], "brdf_log_mse"), \
        medians([r for r in rows if r["render"] == "direct"], "seen_log_mse")
    lines = [f"| scene | m | direct: image rel. MSE blind | aware ({choice}) | change | aware ({other}) | change "
             f"| export: blind | aware ({choice}) | change | seen log-MSE blind | aware | whole BRDF log-MSE blind | aware |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in SCENES:
        for m in ms:
            if (s, m, "blind", "direct") not in med:
                continue
            d = {w: med[(s, m, w, "direct")] for w in ("blind", choice, other)}
            e = {w: med.get((s, m, w, "export"), float("nan")) for w in ("blind", choice)}
            lines.append(f"| {s} | {m} | {d['blind']:.4g} | {d[choice]:.4g} | {100 * (d[choice] / d['blind'] - 1):+.0f} % | "
                         f"{d[other]:.4g} | {100 * (d[other] / d['blind'] - 1):+.0f} % | {e['blind']:.4g} | {e[choice]:.4g} | "
                         f"{100 * (e[choice] / e['blind'] - 1):+.0f} % | {seen[(s, m, 'blind', 'direct')]:.4f} | "
                         f"{seen[(s, m, choice, 'direct')]:.4f} | {brdf[(s, m, 'blind', 'direct')]:.4f} | "
                         f"{brdf[(s, m, choice, 'direct')]:.4f} |")
    return "\n".join(lines)


def goal_table(rows: list[dict], ms: list[int], choice: str) -> str:
    """The goal's table of the direct renders, per scene and m: the medians of the blind and the
    chosen design, their change, the paired median of the ratios (materials better), the chosen
    design at round(0.6 m) when it was rendered and its ratio to blind at m, and whether the goal
    holds (>= 30 % lower at m, or at most blind's error with round(0.6 m) samples)."""
    med = medians(rows)
    lines = ["| scene | m | image rel. MSE blind | aware | change | paired median aware/blind | aware better for "
             "| aware at 0.6 m | that / blind at m | goal |", "|---|---|---|---|---|---|---|---|---|---|"]
    for s in SCENES:
        for m in ms:
            if (s, m, "blind", "direct") not in med:
                continue
            blind, aware = med[(s, m, "blind", "direct")], med[(s, m, choice, "direct")]
            pm, better, n = paired(rows, s, m, choice)
            few = med.get((s, round(0.6 * m), choice, "direct"))
            lower, fewer = aware <= 0.7 * blind, few is not None and few <= blind
            fewer_text = "not rendered" if few is None else f"{few:.4g} (m = {round(0.6 * m)}) | {few / blind:.2f}"
            verdict = "met" + (" (30 % lower)" if lower else "") + (" (fewer)" if fewer else "") \
                if lower or fewer else "not met"
            lines.append(f"| {s} | {m} | {blind:.4g} | {aware:.4g} | {100 * (aware / blind - 1):+.0f} % | {pm:.2f} "
                         f"| {better} / {n} | {fewer_text} | {verdict} |")
    return "\n".join(lines)


def goal_lines(rows: list[dict], ms: list[int], choice: str) -> str:
    """Per scene, render and m: is the chosen design's median error >= 30 % below the blind one's
    at the same m, or at most the blind one's at m with m' <= 0.6 m samples (any m' measured)?"""
    med = medians(rows)
    out = []
    for s in SCENES:
        for render in ("direct", "export"):
            verdicts = []
            for m in ms:
                if (s, m, "blind", render) not in med:
                    continue
                blind = med[(s, m, "blind", render)]
                lower = med[(s, m, choice, render)] <= 0.7 * blind
                fewer = [m2 for (s2, m2, d, r), v in sorted(med.items())
                         if (s2, d, r) == (s, choice, render) and m2 <= 0.6 * m and v <= blind]
                verdicts.append(f"m={m}: {'yes' if lower or fewer else 'no'}"
                                f"{' (30 % lower)' if lower else ''}{f' (m={fewer[0]} <= blind)' if fewer else ''}")
            if verdicts:
                out.append(f"goal {s} {render}: " + "; ".join(verdicts))
    return "\n".join(out)


def save_pictures(pictures: dict, out: Path, choice: str) -> None:
    """One PNG per scene: truth | scene-blind | scene-aware (direct renders), tone-mapped alike."""
    import cv2

    for s in SCENES:
        if (s, "truth") not in pictures:
            continue
        panels = [pictures[(s, k)] for k in ("truth", "blind", choice)]
        top = float(np.percentile(panels[0], 99.5)) or 1.0
        strip = np.concatenate([np.clip(p / top, 0, 1) ** (1 / 2.2) for p in panels], axis=1)
        image = (strip * 255).astype(np.uint8)[..., ::-1]
        image = cv2.resize(image, (image.shape[1] * 3, image.shape[0] * 3), interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(out / f"{s}.png"), image)


if __name__ == "__main__":
    sys.exit(main())
