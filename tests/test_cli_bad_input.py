"""Bad input on the command line: one line naming what was wrong, exit 2, nothing written and
no axis moved, before any long work (the audit of every command against that rule).

Each case is refused before the work it guards: the tests run in well under a second each.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from goniofrost.app.cli import main

REPO = Path(__file__).resolve().parents[1]
SIM_RIG = REPO / "config" / "rigs" / "sim.yaml"


def _refused(capsys, argv) -> str:
    """Run ``goniofrost ARGV``; assert exit 2 and one line on stderr; return that line."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as done:  # argparse's own checks
        code = done.code
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def _tree(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


# ----- usage errors (argparse) are one line too -------------------------------------------------
@pytest.mark.parametrize("argv, words", [
    (["plan", "--model", "m", "--samples", "5", "--max-error", "0.1", "--out", "p.json"],
     "argument --max-error: not allowed with argument --samples"),
    (["train", "--dataset", "builtin", "--components", "abc", "--out", "m"], "invalid int value: 'abc'"),
    (["rig", "lamp", "--rig", "r.yaml", "dim"], "invalid choice: 'dim'"),
    (["rig", "move", "--rig", "r.yaml"], "the following arguments are required: AXIS=DEG"),
    (["preview", "x.binary", "--out", "p.png", "--renderer", "nosuch"], "invalid choice: 'nosuch'"),
])
def test_a_usage_error_is_one_line_naming_the_option_and_help(argv, words, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = _refused(capsys, argv)
    assert words in line and line.endswith("--help)") and line.startswith("goniofrost")
    assert _tree(tmp_path) == []



@pytest.mark.parametrize("argv, line", [
    # the top parser reported these as "goniofrost: error: unrecognized arguments: --sesion s (see goniofrost --help)"
    (["capture", "--rig", "r.yaml", "--plan", "p.json", "--sesion", "s"],
     "goniofrost capture: error: unrecognized option --sesion; did you mean --session? (see goniofrost capture --help)"),
    (["rig", "check", "--rig", "r.yaml", "--ofline"],
     "goniofrost rig check: error: unrecognized option --ofline; did you mean --offline? (see goniofrost rig check --help)"),
    (["preview", "a.binary", "b.binary", "--out", "p.png"],
     "goniofrost preview: error: unrecognized arguments: b.binary (see goniofrost preview --help)"),
    # argparse named the required option the typo was meant to be, not the typo
    (["plan", "--model", "m", "--sampels", "20", "--out", "p.json"],
     "goniofrost plan: error: unrecognized option --sampels; did you mean --samples? (see goniofrost plan --help)"),
    (["materials", "--xyz"], "goniofrost materials: error: unrecognized option --xyz (see goniofrost materials --help)"),
])
def test_a_mistyped_option_is_the_commands_own_error_naming_the_nearest_option(argv, line, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert _refused(capsys, argv) == line
    assert _tree(tmp_path) == []


def test_an_option_abbreviated_unambiguously_is_still_read(tmp_path, capsys, monkeypatch):
    """argparse's prefixes stay as they were: --sampl is --samples (the plan goes on to read the model)."""
    monkeypatch.chdir(tmp_path)
    assert _refused(capsys, ["plan", "--model", "m", "--sampl", "5", "--out", "p.json"]) == (
        "goniofrost plan: error: m: not a goniofrost model (expected a directory with model.json)")



@pytest.mark.parametrize("rig, speedup, line", [
    # a ValueError traceback from the simulated clock (exit 1) after the rig lock was taken
    (SIM_RIG, "0", "goniofrost capture: error: command line: --speedup: expected a simulated clock speed-up > 0, "
                   "found 0.0"),
    (SIM_RIG, "-1", "goniofrost capture: error: command line: --speedup: expected a simulated clock speed-up > 0, "
                    "found -1.0"),
    # silently ignored: a real rig has no simulated clock (the template filled in: "{real}")
    ("{real}", "10",
     "goniofrost capture: error: command line: --speedup: expected no --speedup for the real rig "
     "'my-gonioreflectometer' ({real}), found 10.0"),
])
def test_a_dry_run_checks_its_speedup_as_a_capture_does(rig, speedup, line, tmp_path_factory, tmp_path, capsys,
                                                        monkeypatch):
    if rig == "{real}":
        real = tmp_path_factory.mktemp("real") / "template.yaml"
        real.write_text((REPO / "config" / "rigs" / "template.yaml").read_text().replace("!fill-in ", ""))
        rig, line = real, line.replace("{real}", str(real))
    monkeypatch.chdir(tmp_path)
    assert _refused(capsys, ["capture", "--rig", rig, "--plan", "p.json", "--dry-run", "--speedup", speedup]) == line
    assert _tree(tmp_path) == []



@pytest.mark.parametrize("argv", [
    ["capture", "--rig", SIM_RIG, "--plan", "p.json", "--session", "s", "--material", "builtin:gold"],
    ["align", "--rig", SIM_RIG, "--out", "a.json"],
    ["queue", "q.yaml", "--yes"],
    ["demo", "--out", "d"],
    ["sim", "--rig", SIM_RIG],
    ["bench", "--out", "b"],
])
def test_a_negative_seed_is_a_usage_error_before_anything_is_written(argv, tmp_path, capsys, monkeypatch):
    """numpy refused it with a ValueError traceback (exit 1), after capture had made its session
    folder and journal and demo its plan.json and session."""
    monkeypatch.chdir(tmp_path)
    command = " ".join(argv[:1])
    assert _refused(capsys, [*argv, "--seed", "-1"]) == (
        f"goniofrost {command}: error: argument --seed: expected an integer >= 0, found '-1' "
        f"(see goniofrost {command} --help)")
    assert _tree(tmp_path) == []


# ----- shared small inputs ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def binary(tmp_path_factory) -> Path:
    """A MERL .binary of a 10 x 10 x 20 grid (48 kB)."""
    from goniofrost.brdf.merl_file import valid_to_full, write_merl
    from goniofrost.core.grid import MerlGrid

    grid = MerlGrid(10, 10, 20)
    path = tmp_path_factory.mktemp("inputs") / "x.binary"
    write_merl(path, valid_to_full(np.full((grid.n_valid, 3), 0.2), grid), grid)
    return path


# ----- preview and compare: a sphere too large to draw ------------------------------------------
@pytest.mark.parametrize("command", ["preview", "compare"])
def test_a_sphere_larger_than_2048_pixels_is_refused_before_drawing(command, binary, tmp_path, capsys):
    """--size 100000 asked numpy for 75 GB and ended in a MemoryError traceback (exit 1)."""
    inputs = [binary] if command == "preview" else [binary, binary]
    line = _refused(capsys, [command, *inputs, "--size", "100000", "--out", tmp_path / "p.png"])
    assert line == f"goniofrost {command}: error: --size: expected at most 2048 pixels, found 100000"
    assert _tree(tmp_path) == []


# ----- export: options that would make a file of many GB -------------------------------------------
@pytest.mark.parametrize("options, words", [
    (["--theta-i", "100000"], "--theta-i 100000, --sample 128: the file would hold 19.7 GB of values"),
    (["--sample", "100000"], "--theta-i 48, --sample 100000: the file would hold 5760.0 GB of values"),
    (["--format", "rgl-spectral", "--wavelengths", "100000"], "--wavelengths 100000: the file would hold 314.6 GB"),
])
def test_export_refuses_a_file_of_more_than_1_gb_before_any_work(options, words, binary, tmp_path, capsys):
    """--theta-i 100000 ran for a minute, then the kernel killed it for memory (exit 137)."""
    line = _refused(capsys, ["export", binary, *options, "--out", tmp_path / "e.bsdf"])
    assert words in line and "expected at most 1 GB" in line
    assert _tree(tmp_path) == []


@pytest.mark.parametrize("options, line", [
    (["--theta-i", "100000"], "--theta-i 100000, --sample 128: the file would hold 19.7 GB of values; expected at "
                              "most 1 GB (the defaults hold 9 MB of rgb values)"),
    (["--format", "pbrt", "--wavelengths", "100000"], "--theta-i 48, --sample 128, --wavelengths 100000: the file "
     "would hold 314.6 GB of values; expected at most 1 GB (the defaults hold 101 MB of spectra)"),
])
def test_export_compares_a_too_large_table_with_the_defaults_table_of_its_own_format(options, line, binary,
                                                                                     tmp_path, capsys):
    """It said "(the defaults write 9 MB in RGB)" for every format: the rgb table alone, beside a
    default RGB file of 13.7 MB, and not the spectral table (101 MB) a spectral export is."""
    assert _refused(capsys, ["export", binary, *options, "--out", tmp_path / "e.bsdf"]) == \
        f"goniofrost export: error: {line}"
    assert _tree(tmp_path) == []


# ----- export, convert, plan: an --out whose name says another format ------------------------------
def _no_work(monkeypatch) -> None:
    """Fail the test if export builds its file, convert opens its dataset or plan reads its model."""
    import goniofrost.brdf.formats as formats
    import goniofrost.datasets as datasets
    from goniofrost.frost.model import FrostModel

    monkeypatch.setattr(formats, "export_file", lambda *a, **k: pytest.fail("the file was exported"))
    monkeypatch.setattr(datasets, "open_dataset", lambda *a, **k: pytest.fail("the dataset was opened"))
    monkeypatch.setattr(FrostModel, "load", lambda *a, **k: pytest.fail("the model was read"))


MERL_SUFFIX = ".binary (the file is written in MERL's .binary format)"


@pytest.mark.parametrize("command, out, expected", [
    ("export", "brdf.txt", ".bsdf (every --format writes an RGL tensor file)"),
    ("export --format pbrt", "brdf.binary", ".bsdf (every --format writes an RGL tensor file)"),
    ("export --format rgl-spectral", "brdf.xml", ".bsdf (every --format writes an RGL tensor file)"),
    ("convert", "gold.txt", MERL_SUFFIX),
    ("convert", "gold.bsdf", MERL_SUFFIX),
    ("plan", "plan.yaml", ".json (the plan is written as JSON)"),
    ("plan", "plan", ".json (the plan is written as JSON)"),
    ("reconstruct", "brdf.txt", MERL_SUFFIX),
    ("reconstruct", "brdf", MERL_SUFFIX),
    ("reconstruct --estimator ridge", "s.csv", MERL_SUFFIX),
])
def test_an_out_named_for_another_format_is_refused_before_any_work(command, out, expected, binary, tmp_path,
                                                                     capsys, monkeypatch):
    """export --out brdf.txt wrote an RGL tensor file under a text file's name (exit 0), convert
    --out gold.txt a MERL file, plan --out plan.yaml JSON and reconstruct --out brdf a MERL file
    (brdf.std.binary and brdf.json beside it); the format of each is fixed (export's by --format,
    always an RGL tensor), so a name that says another one is refused, as preview refuses --out
    look.jpg (one check: atomic_file.check_output_suffix)."""
    _no_work(monkeypatch)
    name, *options = command.split()
    argv = {"export": ["export", binary, *options],
            "convert": ["convert", "--dataset", "builtin", "--material", "gold"],
            "plan": ["plan", "--model", tmp_path / "model", "--samples", "5"],
            "reconstruct": ["reconstruct", *options, "--model", tmp_path / "model", "--samples", tmp_path / "s.csv"]
            }[name]
    line = _refused(capsys, [*argv, "--out", tmp_path / out])
    assert line == f"goniofrost {name}: error: --out {tmp_path / out}: expected a file name ending in {expected}"
    assert _tree(tmp_path) == []


@pytest.mark.parametrize("in_the_way", ["a folder", "a file"])
@pytest.mark.parametrize("command, out", [("export", "brdf.bsdf"), ("plan", "plan.json"), ("reconstruct", "brdf.binary")])
def test_an_out_that_cannot_be_written_is_refused_before_any_work(command, out, in_the_way, binary, tmp_path, capsys,
                                                                   monkeypatch):
    """plan --out DIR.json and export --out DIR.bsdf (an existing folder) were refused only when the
    file was written, after the selection or the export; an --out below a file, by these and by
    reconstruct, likewise. One check, atomic_file.check_output_file, as align and sim use."""
    _no_work(monkeypatch)
    if in_the_way == "a folder":
        (tmp_path / out).mkdir()
        where, why = tmp_path / out, "it is a directory; give a file name"
    else:
        (tmp_path / "a-file").write_text("keep me")
        out, where, why = f"a-file/{out}", tmp_path / "a-file", "a part of the path is a file, not a directory"
    before = _tree(tmp_path)
    argv = {"export": ["export", binary],
            "plan": ["plan", "--model", tmp_path / "model", "--samples", "5"],
            "reconstruct": ["reconstruct", "--model", tmp_path / "model", "--samples", tmp_path / "s.csv"]}[command]
    line = _refused(capsys, [*argv, "--out", tmp_path / out])
    assert line == f"goniofrost {command}: error: {where}: cannot write: {why}"
    assert _tree(tmp_path) == before and (in_the_way == "a folder" or (tmp_path / "a-file").read_text() == "keep me")


@pytest.mark.parametrize("out", ["brdf.BSDF", "e.bsdf"])
def test_export_takes_a_bsdf_name_in_any_case(out, binary, tmp_path, capsys):
    assert main(["export", str(binary), "--theta-i", "4", "--sample", "8", "--out", str(tmp_path / out)]) == 0
    assert _tree(tmp_path) == [out]


# ----- preview, export, compare: a MERL file with holes -------------------------------------------
def _damaged(binary: Path, folder: Path, kind: str) -> Path:
    """A copy of ``binary`` (10 x 10 x 20) with holes at the valid cells (2, 3, 4) and (5, 1, 0) and
    at the cell below the horizon (9, 9, 19): stored NaN and inf ("nan"), or -1 ("missing", the
    mark goniofrost writes only below the horizon)."""
    from goniofrost.core.grid import MerlGrid

    grid = MerlGrid(10, 10, 20)
    first, second, below = (2 * 10 + 3) * 20 + 4, (5 * 10 + 1) * 20, grid.size - 1
    assert grid.valid_mask[first] and grid.valid_mask[second] and not grid.valid_mask[below]
    stored = np.fromfile(binary, "<f8", offset=12).reshape(3, grid.size)
    stored[1, first] = np.nan if kind == "nan" else -1.0
    stored[:, second] = np.inf if kind == "nan" else -1.0
    stored[0, below] = np.nan if kind == "nan" else -1.0
    path = folder / f"{kind}.binary"
    path.write_bytes(binary.read_bytes()[:12] + stored.tobytes())
    return path


HOLES = {"nan": "cells holding NaN or inf: 3, first at (i_th, i_td, i_pd) = (2, 3, 4); expected finite values "
                "(-1 marks a missing value)",
         "missing": "valid cells without a value (negative in the file): 2, first at (i_th, i_td, i_pd) = (2, 3, 4); "
                    "expected a BRDF value >= 0 at every cell above the horizon"}


@pytest.mark.parametrize("kind", ["nan", "missing"])
@pytest.mark.parametrize("command", ["preview", "preview --reference", "preview --std", "export mitsuba",
                                     "export rgl-spectral", "compare"])
def test_a_merl_file_with_holes_is_refused_alike_by_preview_export_and_compare(command, kind, binary, tmp_path,
                                                                                capsys):
    """NaN was three policies: preview refused it ("N valid cells hold NaN or infinite values"),
    export refused stored NaN but exported missing valid cells as 0, compare drew them black and
    left them out of the log-relative MSE. Now one check (merl_file.read_merl_complete)."""
    damaged = _damaged(binary, tmp_path, kind)
    argv = {"preview": ["preview", damaged, "--out", tmp_path / "p.png"],
            "preview --reference": ["preview", binary, "--reference", damaged, "--out", tmp_path / "p.png"],
            "preview --std": ["preview", binary, "--std", damaged, "--out", tmp_path / "p.png"],
            "export mitsuba": ["export", damaged, "--format", "mitsuba", "--out", tmp_path / "e.bsdf"],
            "export rgl-spectral": ["export", damaged, "--format", "rgl-spectral", "--out", tmp_path / "e.bsdf"],
            "compare": ["compare", binary, damaged, "--out", tmp_path / "c.png"]}[command]
    line = _refused(capsys, argv)
    assert line == f"goniofrost {command.split()[0]}: error: {damaged}: {HOLES[kind]}"
    assert _tree(tmp_path) == [damaged.name]


# ----- align and sim: an output that cannot be written is refused before any device starts -------
def test_align_refuses_a_directory_as_out_before_any_axis_moves(tmp_path, capsys, monkeypatch):
    """align --out DIR moved the axes through its 30 poses (30 s) and only then failed to write."""
    import goniofrost.rig.hardware as hardware

    monkeypatch.setattr(hardware, "open_hardware", lambda *a, **k: pytest.fail("the rig was started"))
    (tmp_path / "alignment.json").mkdir()
    line = _refused(capsys, ["align", "--rig", SIM_RIG, "--out", tmp_path / "alignment.json"])
    assert line == f"goniofrost align: error: {tmp_path / 'alignment.json'}: cannot write: it is a directory; give a file name"
    assert _tree(tmp_path) == ["alignment.json"]


def test_align_refuses_frames_below_a_file_before_any_axis_moves(binary, tmp_path, capsys, monkeypatch):
    """align --frames FILE moved the axes and then failed with "FILE/align.sqlite: Not a directory"."""
    import goniofrost.rig.hardware as hardware

    monkeypatch.setattr(hardware, "open_hardware", lambda *a, **k: pytest.fail("the rig was started"))
    line = _refused(capsys, ["align", "--rig", SIM_RIG, "--out", tmp_path / "a.json", "--frames", binary])
    assert line == f"goniofrost align: error: {binary}: cannot write: a part of the path is a file, not a directory"
    assert _tree(tmp_path) == []


def test_align_takes_an_out_in_a_folder_it_will_make_as_every_command_does(tmp_path, monkeypatch):
    """align kept its own parent-folder check ("expected a file in an existing folder") beside the
    shared one; now atomic_file.check_output_file alone: a folder that can be made is made, at
    the end, as plan, preview or export make theirs."""
    import goniofrost.rig.hardware as hardware
    from goniofrost.capture.align import align

    class Started(Exception):
        pass

    def start(*args, **kwargs):
        raise Started

    monkeypatch.setattr(hardware, "open_hardware", start)
    with pytest.raises(Started):   # past every check: the rig is started
        align(SIM_RIG, tmp_path / "new" / "alignment.json", progress=False)
    assert _tree(tmp_path) == []   # and nothing made before the run


def test_sim_refuses_a_directory_as_write_rig_before_starting_the_devices(tmp_path, capsys, monkeypatch):
    """sim --write-rig DIR started the simulated devices and the camera service, then failed to write."""
    import sim.rig

    monkeypatch.setattr(sim.rig, "SimulatedRig", lambda *a, **k: pytest.fail("the devices were started"))
    (tmp_path / "lab.yaml").mkdir()
    line = _refused(capsys, ["sim", "--rig", SIM_RIG, "--write-rig", tmp_path / "lab.yaml"])
    assert line == f"goniofrost sim: error: {tmp_path / 'lab.yaml'}: cannot write: it is a directory; give a file name"
    assert _tree(tmp_path) == ["lab.yaml"]


@pytest.mark.parametrize("name", ["lab.json", "lab", "lab.yaml.txt"])
def test_sim_refuses_a_write_rig_not_named_yaml_before_starting_the_devices(name, tmp_path, capsys, monkeypatch):
    """sim --write-rig x.json wrote YAML under a name that says JSON."""
    import sim.rig

    monkeypatch.setattr(sim.rig, "SimulatedRig", lambda *a, **k: pytest.fail("the devices were started"))
    line = _refused(capsys, ["sim", "--rig", SIM_RIG, "--write-rig", tmp_path / name])
    assert line == (f"goniofrost sim: error: --write-rig {tmp_path / name}: expected a file name ending in .yaml or "
                    ".yml (a rig file is written as YAML)")
    assert _tree(tmp_path) == []


def test_reconstruct_refuses_an_out_in_a_folder_that_does_not_exist(tmp_path, capsys):
    """reconstruct --out /nonexistent/dir/x.binary made /nonexistent/dir and exited 0."""
    (tmp_path / "s.csv").write_text("theta_h_deg,theta_d_deg,phi_d_deg,r,g,b\n1,2,3,0.1,0.2,0.3\n")
    out = tmp_path / "nonexistent" / "dir" / "x.binary"
    line = _refused(capsys, ["reconstruct", "--model", tmp_path / "model", "--samples", tmp_path / "s.csv",
                             "--out", out])
    assert line == f"goniofrost reconstruct: error: {out.parent}: cannot write: no such folder; create it first"
    assert _tree(tmp_path) == ["s.csv"]


def test_sim_refuses_material_without_write_rig(capsys, monkeypatch):
    """--material only sets what the camera of --write-rig's rig file sees: without it, it was ignored."""
    import sim.rig

    monkeypatch.setattr(sim.rig, "SimulatedRig", lambda *a, **k: pytest.fail("the devices were started"))
    line = _refused(capsys, ["sim", "--rig", SIM_RIG, "--material", "builtin:gold"])
    assert line.startswith("goniofrost sim: error: command line: --material: expected --write-rig OUT.yaml as well")
    assert line.endswith("found 'builtin:gold'")


# ----- demo: options used minutes later are checked before the training -----------------------------
@pytest.mark.parametrize("options, words", [
    (["--target-error", "0.01", "--confidence", "1.5"],
     "command line: --confidence: expected a probability between 0 and 1 (e.g. 0.95), found 1.5"),
    (["--speedup", "0"], "command line: --speedup: expected a simulated clock speed-up > 0, found 0.0"),
    (["--speedup", "nan"], "command line: --speedup: expected a simulated clock speed-up > 0, found nan"),
    (["--samples", "0"], "command line: --samples: expected an integer in [1, 1000], found 0"),
])
def test_demo_refuses_a_bad_option_before_any_work(options, words, tmp_path, capsys, monkeypatch):
    """--confidence 1.5 and --speedup 0 were refused after training and planning, with plan.json
    (and a session) already written into --out."""
    import goniofrost.app.demo as demo

    monkeypatch.setattr(demo, "run_demo", lambda *a, **k: pytest.fail("the demo ran"))
    line = _refused(capsys, ["demo", "--out", tmp_path / "d", *options])
    assert line == f"goniofrost demo: error: {words}"
    assert _tree(tmp_path) == []


def test_demo_refuses_an_out_below_a_file_before_any_work(binary, capsys, monkeypatch):
    """demo --out FILE trained the model (a minute from an empty cache) before failing."""
    import goniofrost.app.demo as demo

    monkeypatch.setattr(demo, "run_demo", lambda *a, **k: pytest.fail("the demo ran"))
    line = _refused(capsys, ["demo", "--out", binary])
    assert line == f"goniofrost demo: error: {binary}: cannot write: a part of the path is a file, not a directory"


# ----- capture --dry-run: options that a dry run would ignore ---------------------------------------
@pytest.mark.parametrize("options, found", [
    (["--session", "s1"], "--session"),
    (["--target-error", "0.05", "--seed", "0"], "--target-error --seed"),
    (["--material", "builtin:gold", "--bsdf"], "--material --bsdf"),
])
def test_capture_dry_run_refuses_options_it_would_ignore(options, found, tmp_path, capsys, monkeypatch):
    """capture --dry-run --session s1 moved the rig and said nothing of the session it did not write."""
    import goniofrost.app.rig_console as console

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(console, "run_dry_run", lambda *a, **k: pytest.fail("the dry run ran"))
    line = _refused(capsys, ["capture", "--rig", SIM_RIG, "--plan", "plan.json", "--dry-run", *options])
    assert line.startswith("goniofrost capture: error: command line: --dry-run: expected only --rig, --plan, ")
    assert line.endswith(f"found {found!r}")
    assert _tree(tmp_path) == []


# ----- train and bench: numbers checked before the tabulation ----------------------------------------
def test_train_refuses_non_positive_components_before_tabulating(tmp_path, capsys, monkeypatch):
    """train --components -3 tabulated the built-in library (20 s) before the training refused it."""
    import goniofrost.frost.training as training

    monkeypatch.setattr(training, "train", lambda *a, **k: pytest.fail("the training ran"))
    line = _refused(capsys, ["train", "--dataset", "builtin", "--components", "-3", "--out", tmp_path / "m"])
    assert line == ("goniofrost train: error: command line: --components: expected a positive integer "
                    "(the components kept), found -3")
    assert _tree(tmp_path) == []


@pytest.mark.parametrize("options, option, value", [
    (["--jobs", "0"], "--jobs", 0),
    (["--jobs", "-2"], "--jobs", -2),
    (["--stress", "--stress-m", "0"], "--stress-m", 0),
])
def test_bench_refuses_non_positive_jobs_and_stress_m_before_any_work(options, option, value, tmp_path, capsys,
                                                                        monkeypatch):
    """--jobs 0 ran the folds with one worker silently; --stress-m 0 tabulated 151 materials first."""
    import goniofrost.bench.runner as runner

    monkeypatch.setattr(runner, "run_benchmark", lambda *a, **k: pytest.fail("the benchmark ran"))
    monkeypatch.setattr(runner, "run_stress", lambda *a, **k: pytest.fail("the stress cases ran"))
    line = _refused(capsys, ["bench", "--out", tmp_path / "b", "--quick", *options])
    assert line == f"goniofrost bench: error: command line: {option}: expected a positive integer, found {value}"
    assert _tree(tmp_path) == []


def _dead_port() -> int:
    """A loopback port nobody listens on (bound to be given one, then closed)."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.parametrize("options, found", [(["--dask", "tcp://127.0.0.1:1"], "--dask"),
                                            (["--resume"], "--resume"),
                                            (["--resume", "--dask", "tcp://127.0.0.1:1"], "--dask --resume")])
def test_bench_stress_refuses_the_options_it_would_ignore(options, found, tmp_path, capsys, monkeypatch):
    """bench --stress --dask ADDRESS ran the stress cases here and said nothing of the scheduler."""
    import goniofrost.bench.runner as runner

    monkeypatch.setattr(runner, "run_stress", lambda *a, **k: pytest.fail("the stress cases ran"))
    line = _refused(capsys, ["bench", "--out", tmp_path / "b", "--stress", *options])
    assert line == ("goniofrost bench: error: command line: --stress: expected no --dask or --resume (the stress "
                    f"cases run in this process, in one pass), found {found!r}")
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("options, line", [
    (["--stress", "--methods", "frost"], "--stress: expected no --methods, --folds, --target-error or --nielsen-trials "
     "(the stress cases run every method once, on fold 0, without a simulated capture), found '--methods'"),
    (["--stress", "--folds", "3", "--target-error", "0.02"], "--stress: expected no --methods, --folds, --target-error "
     "or --nielsen-trials (the stress cases run every method once, on fold 0, without a simulated capture), found "
     "'--folds --target-error'"),
    (["--methods", "frost,random", "--target-error", "0.02"], "--target-error: expected --methods with bayes (the "
     "simulated capture --target-error runs the Bayesian design), found 'frost,random'")])
def test_bench_refuses_options_the_run_would_ignore(options, line, tmp_path, capsys, monkeypatch):
    """bench --stress --methods frost ran and listed all six methods in stress.md; --methods frost
    --target-error 0.02 wrote no target row; neither said so."""
    import goniofrost.bench.runner as runner

    monkeypatch.setattr(runner, "tables_path", lambda *a, **k: pytest.fail("the materials were tabulated"))
    assert _refused(capsys, ["bench", "--out", tmp_path / "b", *options]) == f"goniofrost bench: error: command line: {line}"
    assert not (tmp_path / "b").exists()


def test_bench_refuses_an_unreachable_dask_scheduler_at_once(tmp_path, capsys, monkeypatch):
    """--dask ADDRESS with no scheduler there tabulated the materials first, then waited out
    dask's 30 s connect timeout."""
    import time

    import goniofrost.bench.runner as runner

    pytest.importorskip("distributed")
    monkeypatch.setattr(runner, "tables_path", lambda *a, **k: pytest.fail("the materials were tabulated"))
    address = f"tcp://127.0.0.1:{_dead_port()}"
    started = time.monotonic()
    line = _refused(capsys, ["bench", "--out", tmp_path / "b", "--quick", "--dask", address])
    assert line == f"goniofrost bench: error: --dask {address}: cannot connect to a Dask scheduler there " \
                   f"(Connection refused)"
    assert time.monotonic() - started < 10   # a refused connect is not retried for 30 s
    assert _tree(tmp_path) == []


def test_run_folds_refuses_an_unreachable_dask_scheduler_before_handing_it_to_dask(monkeypatch):
    import distributed

    from goniofrost.bench.config import BenchConfig, BenchError
    from goniofrost.bench.executors import run_folds

    monkeypatch.setattr(distributed, "Client", lambda *a, **k: pytest.fail("dask was asked to connect"))
    address = f"127.0.0.1:{_dead_port()}"
    with pytest.raises(BenchError) as refused:
        run_folds(BenchConfig(("builtin",), folds=1), "tables.npy", ["m"], dask_address=address, progress=False)
    assert str(refused.value) == f"--dask {address}: cannot connect to a Dask scheduler there (Connection refused)"


# ----- a damaged model.json -------------------------------------------------------------------------
GOOD_META = {"format": "goniofrost-frost-model", "version": 2, "grid": {"n_th": 10, "n_td": 10, "n_pd": 20},
             "names": ["m0", "m1"], "eps": 0.001, "content_hash": "0" * 64, "info": {}, "noise": {}}


@pytest.mark.parametrize("field, value, words", [
    ("grid", "abc", 'grid: expected {"n_th": int, "n_td": int, "n_pd": int} (positive), found \'abc\''),
    ("grid", {"n_th": 10, "n_td": -1, "n_pd": 20}, "grid: expected"),
    ("names", "m0", "names: expected a list of material names, found 'm0'"),
    ("eps", "small", "eps: expected a finite number >= 0, found 'small'"),
    ("noise", [1], "noise: expected a JSON object, found [1]"),
])
@pytest.mark.parametrize("command", ["plan", "reconstruct"])
def test_a_model_json_field_of_the_wrong_type_is_named(command, field, value, words, tmp_path, capsys):
    """model.json with "grid": "abc" ended in a TypeError traceback (exit 1) in plan and reconstruct."""
    import json

    from goniofrost.frost.model import FORMAT

    model = tmp_path / "model"
    model.mkdir()
    (model / "model.json").write_text(json.dumps(GOOD_META | {"format": FORMAT, field: value}))
    (tmp_path / "s.csv").write_text("theta_h_deg,theta_d_deg,phi_d_deg,r,g,b\n1,2,3,0.1,0.2,0.3\n")
    before = _tree(tmp_path)
    argv = {"plan": ["plan", "--model", model, "--samples", "3", "--out", tmp_path / "p.json"],
            "reconstruct": ["reconstruct", "--model", model, "--samples", tmp_path / "s.csv",
                            "--out", tmp_path / "r.binary"]}[command]
    line = _refused(capsys, argv)
    assert line.startswith(f"goniofrost {command}: error: {model / 'model.json'}: {words}")
    assert _tree(tmp_path) == before


# ----- reconstruct: an --out that is the samples file ------------------------------------------------
@pytest.mark.parametrize("out, samples, clash, option", [
    ("s.binary", "s.binary", "s.binary", "--samples s.binary"),   # (--out s.csv: refused by its suffix first)
    ("s.binary", "s.json", "s.json", "--samples s.json"),     # its record OUT.json
    ("model/brdf.binary", "s.csv", "model/brdf.binary", "--model model"),
])
def test_reconstruct_refuses_an_out_that_would_overwrite_an_input(out, samples, clash, option, tmp_path, capsys,
                                                                    monkeypatch):
    """reconstruct --samples s.csv --out s.csv replaced the samples with the BRDF (exit 0); with
    --samples s.json --out s.binary the record OUT.json would replace them. The check is the
    bottom layer's (atomic_file.check_not_an_input), which also keeps --out out of the model."""
    monkeypatch.chdir(tmp_path)
    text = "theta_h_deg,theta_d_deg,phi_d_deg,r,g,b\n1,2,3,0.1,0.2,0.3\n"
    Path(samples).write_text(text)
    Path("model").mkdir()
    line = _refused(capsys, ["reconstruct", "--model", "model", "--samples", samples, "--out", out])
    name, path = option.split()
    here = tmp_path.resolve()
    assert line == (f"goniofrost reconstruct: error: {here / clash}: cannot write: --out would overwrite the input "
                    f"{name} {here / path}; give another name")
    assert _tree(tmp_path) == sorted(["model", samples]) and Path(samples).read_text() == text


# ----- an output that is one of the command's inputs -------------------------------------------------
def test_plan_refuses_an_out_inside_its_model(tmp_path, capsys):
    """plan --out MODEL/model.json replaced the model's metadata with the plan (exit 0): the model was lost."""
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.json").write_text("{}")
    line = _refused(capsys, ["plan", "--model", model, "--samples", "3", "--out", model / "model.json"])
    assert line == (f"goniofrost plan: error: {model / 'model.json'}: cannot write: --out would overwrite the input "
                    f"--model {model}; give another name")
    assert (model / "model.json").read_text() == "{}"


def test_sim_refuses_a_write_rig_that_is_its_rig(tmp_path, capsys, monkeypatch):
    """sim --rig lab.yaml --write-rig lab.yaml replaced the rig file with the generated one."""
    import sim.rig

    monkeypatch.setattr(sim.rig, "SimulatedRig", lambda *a, **k: pytest.fail("the devices were started"))
    rig = tmp_path / "lab.yaml"
    rig.write_text(SIM_RIG.read_text())
    line = _refused(capsys, ["sim", "--rig", rig, "--write-rig", rig])
    assert line == (f"goniofrost sim: error: {rig}: cannot write: --write-rig would overwrite the input --rig {rig}; "
                    f"give another name")
    assert rig.read_text() == SIM_RIG.read_text() and _tree(tmp_path) == ["lab.yaml"]


def test_align_refuses_an_out_that_is_its_rig(tmp_path, capsys, monkeypatch):
    import goniofrost.rig.hardware as hardware

    monkeypatch.setattr(hardware, "open_hardware", lambda *a, **k: pytest.fail("the rig was started"))
    rig = tmp_path / "lab.yaml"
    rig.write_text(SIM_RIG.read_text())
    line = _refused(capsys, ["align", "--rig", rig, "--out", rig])
    assert line.endswith(f"cannot write: --out would overwrite the input --rig {rig}; give another name")
    assert rig.read_text() == SIM_RIG.read_text()


def test_usage_refuses_an_out_that_is_not_npy_before_it_renders(tmp_path, capsys, monkeypatch):
    """usage --out usage.png wrote the weights' NumPy bytes under a picture's name, after the render."""
    import goniofrost.brdf.mitsuba_usage as mitsuba_usage

    monkeypatch.setattr(mitsuba_usage, "record_usage", lambda *a, **k: pytest.fail("the scene was rendered"))
    line = _refused(capsys, ["usage", "--scene", tmp_path / "scene.xml", "--object", "sample",
                             "--out", tmp_path / "usage.png"])
    assert line == (f"goniofrost usage: error: --out {tmp_path / 'usage.png'}: expected a file name ending in .npy "
                    "(the weights are a NumPy array)")   # the message of every --out suffix check
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("samples", ["0", "-3"])
def test_plan_refuses_a_non_positive_sample_count_naming_the_option(samples, tmp_path, capsys):
    """plan --samples 0 said 'samples m: expected an integer in [1, 60]', after loading the model."""
    line = _refused(capsys, ["plan", "--model", tmp_path / "no-model", "--samples", samples,
                             "--out", tmp_path / "plan.json"])
    assert line == f"goniofrost plan: error: command line: --samples: expected a positive integer, found {samples}"
    assert list(tmp_path.iterdir()) == []


def test_output_read_by_a_reader_that_goes_away_ends_quietly_as_sigpipe_would():
    """``goniofrost materials ... | head -1``: no "error: Broken pipe" and no exit 2 (the reader
    closed the pipe; the command ends as a tool killed by SIGPIPE, 141)."""
    import os
    import subprocess
    import sys

    read, write = os.pipe()
    os.close(read)  # the reader is gone before the first line: every write meets a closed pipe
    proc = subprocess.Popen([sys.executable, "-m", "goniofrost", "materials", "--dataset", "builtin"],
                            stdout=write, stderr=subprocess.PIPE, cwd=REPO)
    os.close(write)
    _, err = proc.communicate(timeout=120)
    assert err.decode().strip() == ""
    assert proc.returncode == 141


@pytest.mark.parametrize("argv, line", [
    (["queue", "add", "--plan", "plan.json", "--sample-id", "s1"],
     "goniofrost queue: error: command line: --rig: expected a value with goniofrost queue add, found None"),
    (["queue", "add", "--rig", SIM_RIG, "--plan", "plan.json", "--sample-id", "s1"],
     f"goniofrost queue: error: --rig: no goniofrost serve holds the devices of {SIM_RIG}: start one (goniofrost "
     f"serve --rig {SIM_RIG} --root DIR), or list the sample in a queue file (goniofrost queue QUEUE.yaml)"),
    (["queue", "q.yaml", "--sample-id", "s1"],
     "goniofrost queue: error: command line: --sample-id: expected only with goniofrost queue add (a queue file "
     "names its own), found 's1'"),
])
def test_queue_add_without_its_options_or_a_server_is_one_line_and_queues_nothing(argv, line, tmp_path, capsys,
                                                                                    monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert _refused(capsys, argv) == line
    assert _tree(tmp_path) == []
