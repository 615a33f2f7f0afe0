"""The whole chain on the simulated rig with the built-in library: ``goniofrost demo``.

train (built-in library minus the demo material, cached) -> Bayesian plan of up to m samples on
the simulated rig, in batches -> capture of the held-out material with sensor noise (journaled
session) that stops once the material's error is at most the target with 95 % confidence (the
calibrated bound of frost.confidence) -> reconstruction
with its uncertainty on the full MERL grid -> ground-truth MERL file, preview PNG (with the
predicted uncertainty beside the actual error), report (predicted against actual error).
"""
from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.atomic_file import write_text_atomic
from goniofrost.capture.options import StopRule

DEFAULT_MATERIAL = "red-plastic"
DEFAULT_SAMPLES = 40  # the plan's m_max; the capture stops earlier once the target is met
# log-relative MSE E, i.e. an RMS error of about sqrt(E) = 7 % in the log of the cosine-weighted BRDF
# (rms_relative_error). 0.05 (22 %) told nothing on the built-in library: its bound after the first
# batch is far below it, so every capture stopped there whatever the material.
DEFAULT_TARGET_ERROR = 0.005
DEFAULT_CONFIDENCE = 0.95
DEFAULT_SPEEDUP = 50.0  # simulated seconds per real second: motion and exposures of the demo rig
# what the demo writes into its --out folder besides the session folder (which it replaces whole)
DEMO_FILES = ("plan.json", "reference.binary", "preview.png", "report.json")


def rms_relative_error(log_relative_mse: float) -> float:
    """The RMS relative error a log-relative MSE E stands for: sqrt(E) (log(1 + x) ~ x), 0.005 ~ 7 %."""
    return log_relative_mse ** 0.5


def default_rig_path() -> Path:
    """The simulated rig file (config/rigs/sim.yaml, shipped in the package as rigs/sim.yaml)."""
    return Path(__file__).resolve().parents[1] / "rigs" / "sim.yaml"


@dataclass
class DemoResult:
    """Paths written by the demo, its report and the wall time of each stage (s)."""

    out: Path
    report: dict
    stages_s: dict


@dataclass(frozen=True)
class DemoRequest:
    """What the demo measures: built-in ``material`` (left out of training), a plan of up to
    ``samples`` on the rig of ``rig_path`` (None: ``default_rig_path``) over ``grid`` (None: the
    full grid), the simulated noise ``seed`` and clock ``speedup``; ``bsdf``: also export the
    session's brdf.binary to brdf.bsdf for Mitsuba 3 (stage "export"); ``stop``: stop the capture
    once the error is at most its target with its confidence (a target None: all samples)."""

    material: str = DEFAULT_MATERIAL
    samples: int = DEFAULT_SAMPLES
    rig_path: str | Path | None = None
    grid: object = None
    seed: int = 0
    speedup: float = DEFAULT_SPEEDUP
    bsdf: bool = False
    stop: StopRule = StopRule(DEFAULT_TARGET_ERROR, DEFAULT_CONFIDENCE)


def run_demo(out, request: DemoRequest = DemoRequest(), progress: bool = True) -> DemoResult:
    """Run the demo of ``request`` into folder ``out`` (a previous demo's results there are replaced)."""
    from goniofrost.core.grid import FULL_GRID

    material, samples = request.material, request.samples
    out, grid = Path(out), request.grid or FULL_GRID
    rig_path = Path(request.rig_path) if request.rig_path else default_rig_path()
    check_replaceable(out / "session")  # before minutes of training, not after
    check_demo_outputs(out)
    from goniofrost.datasets import open_dataset

    open_dataset("builtin").resolve(material)  # an unknown name fails here, with suggestions
    stages, clock = {}, time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        stages[name], clock = now - clock, now

    # The rig's reachability map (cached on disk after the first run) comes first: the model's
    # sentinel check is calibrated at cells this rig can measure (as ``train --rig``), so the plan
    # measures its sentinels exactly there. A bad rig file fails here, before the training.
    from concurrent.futures import ThreadPoolExecutor

    from goniofrost.rig.file import command_steps, load_checked_rig
    from goniofrost.rig.lock import check_free
    from planner.reach import is_cached, reachability

    rig = load_checked_rig(rig_path)
    steps = command_steps(rig)  # measurable at the joints the plan commands (planner.candidates)
    check_free(rig)  # a rig another program drives fails here, not after the training
    with ThreadPoolExecutor(1, thread_name_prefix="demo-tabulate") as pool:
        # A first run: the training materials are tabulated (what training reads first, and needs
        # no reach map) on another core while the map is computed (numpy frees the GIL)
        tabulating = None if is_cached(rig, grid, steps) else pool.submit(tabulate_training_set, material, grid)
        reach = reachability(rig, grid, steps=steps)
        if tabulating is not None:
            tabulating.result()
    lap("reach")
    note = training_note(material, grid, reach.mask) if progress else None
    if note:
        print(note, file=sys.stderr, flush=True)
    model, model_path = train_without(material, grid, progress, reach.mask)
    lap("train")
    from goniofrost.plan.make import PlanRequest

    plan_path = plan_on_rig(model, model_path, PlanRequest(samples=samples, rig=rig, candidates=reach.mask),
                            out / "plan.json")
    lap("plan")
    from goniofrost.capture.inputs import inputs_on
    from goniofrost.datasets import shown_material
    from goniofrost.rig.hardware import SimOptions

    shown = shown_material(f"builtin:{material}")  # the camera's, and the report's ground truth
    sim = SimOptions(material=shown, seed=request.seed, speedup=request.speedup)
    outcome = capture_fresh(inputs_on(rig, plan_path), out / "session", sim, request.stop, progress)
    lap("capture")
    write_reference_and_preview(shown, grid, out)
    lap("reference")
    if request.bsdf:
        from goniofrost.brdf.formats import export_beside
        export_beside(out / "session" / "brdf.binary", "mitsuba")
        lap("export")
    report = {**outcome.report, "demo": {"material": f"builtin:{material}", "m_max": samples,
                                         "target_error": request.stop.target_error,
                                         "confidence": request.stop.confidence,
                                         "rig": str(rig_path),
                                         "rendering_snr_db": outcome.report["rendering_snr_db"], "stages_s": stages,
                                         "total_s": sum(stages.values())}}
    write_text_atomic(out / "report.json", json.dumps(report, indent=1))
    return DemoResult(out, report, stages)


def tabulate_training_set(material: str, grid) -> None:
    """Tabulate (into the tabulation cache) the built-in library without ``material``: the
    materials ``train_without`` trains on."""
    from goniofrost.datasets.tabulate import collect_materials, tabulated_material_files

    tabulated_material_files(collect_materials(["builtin"], None, [material]), grid, progress=False)


# what a first training of the demo's model took: 45 s on a quiet 2-core machine, 74 s at load 6 to 9
TRAINING_TAKES = "about 1 to 2 min on 2 cores"


def training_note(material: str, grid, sentinel_candidates=None) -> str | None:
    """What the demo says before it trains its model (None when the model is cached: no wait)."""
    from goniofrost.datasets.tabulate import collect_materials
    from goniofrost.frost.training import trained_model_folder

    if (trained_model_folder(["builtin"], exclude=[material], grid=grid,
                             sentinel_candidates=sentinel_candidates) / "model.json").is_file():
        return None
    n = len(collect_materials(["builtin"], None, [material]))
    return (f"demo: training the model on the {n} built-in materials other than {material} "
            f"({TRAINING_TAKES}; once: the model is cached for the next demo)")


def train_without(material: str, grid, progress: bool, sentinel_candidates=None):
    """Train on the built-in library without ``material`` (cached; the sentinel check calibrated
    among ``sentinel_candidates``, a rig's measurable cells, or the whole grid); return (model,
    its folder)."""
    from goniofrost.core.cache import cache_path
    from goniofrost.datasets import open_dataset
    from goniofrost.frost.training import train

    open_dataset("builtin").resolve(material)  # an unknown name fails here, with suggestions
    model = train(["builtin"], exclude=[material], grid=grid, cache=True, progress=progress,
                  sentinel_candidates=sentinel_candidates)
    return model, cache_path("models", model.info["cache_key"], "")


def plan_on_rig(model, model_path, request, out_path) -> Path:
    """Select and schedule the cells of ``request`` (``goniofrost.plan.make.PlanRequest``: its
    ``rig`` decides what can be reached and measured) with the model at ``model_path``, write
    PLAN.json to ``out_path`` and return its path."""
    from goniofrost.plan.file import write_plan
    from goniofrost.plan.make import make_plan

    write_plan(out_path, make_plan(model, model_path, request).doc)
    return Path(out_path)


RERUN_DEMO = "the demo again"  # what a stopped demo says to type: it has no --resume and starts a new session


def capture_fresh(inputs, session_dir: Path, sim, stop, progress: bool):
    """Capture ``inputs`` (``goniofrost.capture.inputs``) into a fresh session folder (a previous
    demo session there is removed first), on the simulated devices of its rig with ``sim``
    (``goniofrost.rig.hardware.SimOptions``: the material shown, the seed, the speed-up),
    stopping by ``stop`` (``goniofrost.capture.target.StopRule``)."""
    from goniofrost.app.ground_truth import GroundTruth
    from goniofrost.capture.options import SessionOptions
    from goniofrost.capture.runner import capture
    from goniofrost.rig.simulated import rig_devices

    check_replaceable(session_dir)
    if session_dir.exists():
        shutil.rmtree(session_dir)
    return capture(inputs, session_dir, devices=rig_devices, sim=sim, stop=stop,
                   options=SessionOptions(progress=progress, rerun=RERUN_DEMO, compare=GroundTruth(sim.material)))


def check_replaceable(session_dir: Path) -> None:
    """Refuse to replace a folder that is not a previous demo session (it has no journal)."""
    from goniofrost.capture.runner import JOURNAL_FILE

    if session_dir.exists() and not (session_dir / JOURNAL_FILE).is_file():
        raise GoniofrostError(f"{session_dir}: exists but holds no {JOURNAL_FILE}, so it is not a previous demo "
                              f"session; refusing to delete it: choose another --out")


def check_demo_outputs(out: Path) -> None:
    """OutputError now, before the training, for a folder where one of DEMO_FILES goes (a folder
    named report.json was found after the whole capture). Nothing in the session folder can be in
    the way: ``capture_fresh`` replaces it whole, so its brdf.bsdf (``--bsdf``) is never checked."""
    from goniofrost.core.atomic_file import check_output_file

    for name in DEMO_FILES:
        check_output_file(out / name, "it is a directory, where the demo writes a file: move it away or choose "
                                      "another --out")


def write_reference_and_preview(material, grid, out: Path) -> None:
    """Write the ground truth (``material``: the ShownMaterial the capture was handed) as
    reference.binary; the session's preview (already rendered against the same truth) becomes
    out/preview.png."""
    from goniofrost.brdf.merl_file import valid_to_full, write_merl
    from goniofrost.app.ground_truth import ground_truth

    truth = ground_truth(material, grid)  # the table the session report used
    write_merl(out / "reference.binary", valid_to_full(truth, grid), grid)
    from goniofrost.core.atomic_file import write_bytes_atomic

    # atomic as every other file the demo writes: a reader (or a failure) sees the old picture or the new
    write_bytes_atomic(out / "preview.png", (out / "session" / "preview.png").read_bytes())
