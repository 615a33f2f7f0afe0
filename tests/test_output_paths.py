"""Every output path a user can get wrong is a one-line error with exit 2, and nothing is left behind.

The read-only and the full file systems are real: small tmpfs mounts (the suite runs as root in
CI; where mounting is not allowed those two cases are skipped, the others still run).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from goniofrost.app.cli import main
from goniofrost.brdf.merl_file import valid_to_full, write_merl
from goniofrost.core.atomic_file import write_bytes_atomic
from goniofrost.core.errors import OutputError
from goniofrost.core.grid import MerlGrid
from goniofrost.frost.outputs import bayes_output_paths
from goniofrost.frost.selection import select_cells
from goniofrost.frost.training import TrainingOptions, fit_model

GRID = MerlGrid(10, 10, 20)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A small model, a SAMPLES.csv of 6 of its cells and a .binary of the grid."""
    folder = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(3)
    th = GRID.flat_angles(GRID.valid_cells)[0]
    tables = np.stack([rng.uniform(0.05, 0.3, 3) + rng.uniform(1, 20) * np.cos(th)[:, None] ** rng.uniform(5, 80)
                       for _ in range(10)]).astype(np.float32)
    model = fit_model(tables, [f"m{i}" for i in range(10)], GRID, TrainingOptions(k_max=8))
    model.save(folder / "model")
    cells = GRID.valid_cells[select_cells(model, 6).positions]
    angles = np.degrees(np.stack(GRID.flat_angles(cells), axis=1))
    (folder / "s.csv").write_text("theta_h_deg,theta_d_deg,phi_d_deg,r,g,b\n" + "".join(
        f"{a},{b},{c},0.1,0.2,0.3\n" for a, b, c in angles))
    write_merl(folder / "x.binary", valid_to_full(tables[0], GRID), GRID)
    return folder


def _command(name: str, inputs: Path, out: Path) -> list[str]:
    return {
        "plan": ["plan", "--model", str(inputs / "model"), "--samples", "5", "--out", str(out)],
        "reconstruct": ["reconstruct", "--model", str(inputs / "model"), "--samples", str(inputs / "s.csv"),
                        "--out", str(out)],
        "preview": ["preview", str(inputs / "x.binary"), "--size", "32", "--out", str(out)],
        "export": ["export", str(inputs / "x.binary"), "--theta-i", "4", "--sample", "8", "--out", str(out)],
    }[name]


COMMANDS = ("plan", "reconstruct", "preview", "export")
# those that check their --out before the work (atomic_file.check_output_file): a folder that cannot
# be written is named itself, the file in the way or the read-only folder, as train and convert do
CHECKED_FIRST = ("plan", "reconstruct", "export")


# the suffix a command's --out must end in (reconstruct's OUT.std.binary and OUT.json go beside it)
SUFFIXES = {"preview": ".png", "plan": ".json", "export": ".bsdf", "reconstruct": ".binary"}


def _named(name: str, path: Path) -> Path:
    """``path`` as the command's --out, with the suffix of the file it writes (a picture .png, a
    plan .json, an RGL tensor .bsdf, a MERL .binary)."""
    return path.with_name(path.name + SUFFIXES.get(name, ""))


def _run(capsys, argv) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


def test_the_commands_write_where_they_should(inputs, tmp_path, capsys):
    for name in COMMANDS:
        out = _named(name, tmp_path / f"{name}.out")
        assert _run(capsys, _command(name, inputs, out))[0] == 0 and out.is_file()


def test_reconstruct_takes_a_binary_name_in_any_case_and_puts_its_side_files_beside_it(inputs, tmp_path, capsys):
    """--out is checked for .binary in any case (check_output_suffix); OUT.BINARY's side files were
    OUT.BINARY.std.binary and OUT.BINARY.json, not OUT.std.binary and OUT.json as for OUT.binary."""
    assert _run(capsys, _command("reconstruct", inputs, tmp_path / "o.BINARY"))[0] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.BINARY", "o.json", "o.std.binary"]


@pytest.mark.parametrize("name", (*COMMANDS, "compare"))
def test_an_existing_out_is_replaced_by_a_rename(inputs, tmp_path, capsys, name):
    """What the README promises: an existing --out is replaced atomically (a temporary file beside
    it, renamed over it). A reader that opened the old file still reads all of it (a write in
    place would truncate it), the path holds the new file, and no temporary file is left."""
    out = _named("preview" if name == "compare" else name, tmp_path / f"{name}.out")
    argv = (["compare", str(inputs / "x.binary"), str(inputs / "x.binary"), "--size", "32", "--out", str(out)]
            if name == "compare" else _command(name, inputs, out))
    outs = [out] + (list(bayes_output_paths(out)) if name == "reconstruct" else [])   # OUT.std.binary, OUT.json
    old = b"the old file " * 1000
    readers = []
    for path in outs:
        path.write_bytes(old)
        readers.append(open(path, "rb"))
    try:
        assert _run(capsys, argv)[0] == 0
        for path, reader in zip(outs, readers):
            assert reader.read() == old                      # the old file, untouched
            assert path.read_bytes() != old and os.fstat(reader.fileno()).st_ino != path.stat().st_ino
    finally:
        for reader in readers:
            reader.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in outs)


@pytest.mark.parametrize("name", COMMANDS)
def test_out_that_is_a_directory(inputs, tmp_path, capsys, name):
    out = _named(name, tmp_path / "a-folder")
    out.mkdir()
    code, err = _run(capsys, _command(name, inputs, out))
    assert code == 2 and err == f"goniofrost {name}: error: {out}: cannot write: it is a directory; give a file name"
    assert list(out.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == [out.name]


@pytest.mark.parametrize("name", COMMANDS)
def test_out_below_a_file(inputs, tmp_path, capsys, name):
    (tmp_path / "a-file").write_text("keep me")
    out = _named(name, tmp_path / "a-file" / "result")
    code, err = _run(capsys, _command(name, inputs, out))
    named = tmp_path / "a-file" if name in CHECKED_FIRST else out
    assert code == 2 and err == (f"goniofrost {name}: error: {named}: cannot write: "
                                 "a part of the path is a file, not a directory")
    assert (tmp_path / "a-file").read_text() == "keep me"


@pytest.mark.parametrize("name", COMMANDS)
def test_out_on_a_read_only_file_system(inputs, mounted, capsys, name):
    folder = mounted("ro,size=64k")
    out = _named(name, folder / "result")
    code, err = _run(capsys, _command(name, inputs, out))
    named = folder if name in CHECKED_FIRST else out
    assert code == 2 and err == f"goniofrost {name}: error: {named}: cannot write: the file system is read-only"
    assert list(folder.iterdir()) == []


@pytest.mark.parametrize("name", ["reconstruct", "preview"])
def test_out_on_a_full_disk_leaves_no_partial_file(inputs, mounted, capsys, name):
    folder = mounted("size=64k")
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as handle:   # fill it: the next write gets ENOSPC
        with pytest.raises(OSError, match="No space left"):
            while True:
                handle.write(b"\0" * 4096)
    out = _named(name, folder / "result")
    code, err = _run(capsys, _command(name, inputs, out))
    assert code == 2 and err == f"goniofrost {name}: error: {out}: cannot write: no space left on the device"
    assert [p.name for p in folder.iterdir()] == ["filler"]


def test_model_save_into_a_file_path(inputs, tmp_path):
    from goniofrost.frost.model import FrostModel

    (tmp_path / "a-file").write_text("x")
    with pytest.raises(OutputError, match="a part of the path is a file, not a directory"):
        FrostModel.load(inputs / "model").save(tmp_path / "a-file" / "model")


def test_atomic_write_keeps_the_old_file_when_the_new_one_fails(mounted):
    folder = mounted("size=64k")
    target = folder / "result"
    write_bytes_atomic(target, b"old")
    with pytest.raises(OutputError, match="no space left"):
        write_bytes_atomic(target, b"x" * 200_000)
    assert target.read_bytes() == b"old" and [p.name for p in folder.iterdir()] == ["result"]


def test_a_directory_given_as_a_merl_file_is_a_one_line_error(tmp_path, capsys):
    code, err = _run(capsys, ["preview", str(tmp_path), "--out", str(tmp_path / "x.png")])
    assert code == 2 and err == f"goniofrost preview: error: {tmp_path}: cannot read: Is a directory"
    assert list(tmp_path.iterdir()) == []


def test_bench_refuses_a_bad_out_before_any_work(tmp_path, capsys):
    (tmp_path / "a-file").write_text("x")
    out = tmp_path / "a-file"
    code, err = _run(capsys, ["bench", "--quick", "--grid", "4,4,8", "--out", str(out), "--no-progress"])
    assert code == 2 and err == f"goniofrost bench: error: {out}: cannot write: a part of the path is a file, not a directory"
    assert "bench:" not in capsys.readouterr().err


def test_check_output_dir_creates_nothing_and_names_the_problem(tmp_path, mounted):
    from goniofrost.core.atomic_file import check_output_dir

    check_output_dir(tmp_path / "new" / "deeper")
    assert list(tmp_path.iterdir()) == []
    read_only = mounted("ro,size=64k")
    with pytest.raises(OutputError, match="read-only"):
        check_output_dir(read_only / "out")


# ----- train and convert: checked before the long work, one line, exit 2 -------------------------
def _train(out: Path) -> list[str]:
    return ["train", "--dataset", "builtin", "--only", "gold", "--out", str(out)]


def _convert(out: Path) -> list[str]:
    out = out if out.suffix == ".binary" else out.with_name(out.name + ".binary")   # the MERL file's suffix
    return ["convert", "--dataset", "builtin", "--material", "red-plastic", "--out", str(out)]


def test_train_and_convert_refuse_an_out_below_a_file(tmp_path, capsys):
    (tmp_path / "a-file").write_text("keep me")
    for name, argv in (("train", _train), ("convert", _convert)):
        out = tmp_path / "a-file" / "result"
        code, err = _run(capsys, argv(out))
        assert code == 2 and err == (f"goniofrost {name}: error: {tmp_path / 'a-file'}: cannot write: "
                                     "a part of the path is a file, not a directory")
    assert (tmp_path / "a-file").read_text() == "keep me" and len(list(tmp_path.iterdir())) == 1


def test_train_and_convert_refuse_an_out_on_a_read_only_file_system(mounted, capsys):
    folder = mounted("ro,size=64k")
    for name, argv in (("train", _train), ("convert", _convert)):
        code, err = _run(capsys, argv(folder / "result"))
        assert code == 2 and err == f"goniofrost {name}: error: {folder}: cannot write: the file system is read-only"


def test_train_refuses_an_existing_folder_that_is_no_model_and_convert_a_folder(tmp_path, capsys):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "keep.jpg").write_text("x")
    code, err = _run(capsys, _train(tmp_path / "photos"))
    assert code == 2 and err == (f"goniofrost train: error: {tmp_path / 'photos'}: exists and is not a model "
                                 "directory; refusing to overwrite")
    (tmp_path / "photos.binary").mkdir()
    code, err = _run(capsys, _convert(tmp_path / "photos.binary"))
    assert code == 2 and err == (f"goniofrost convert: error: {tmp_path / 'photos.binary'}: cannot write: it is a "
                                 "directory; give a file name such as red-plastic.binary")
    assert [p.name for p in (tmp_path / "photos").iterdir()] == ["keep.jpg"]
    assert list((tmp_path / "photos.binary").iterdir()) == []


def test_convert_on_a_full_disk_leaves_no_partial_file(mounted, capsys):
    folder = mounted("size=64k")  # the full-grid .binary is 26 MB
    out = folder / "red.binary"
    code, err = _run(capsys, _convert(out))
    assert code == 2 and err == f"goniofrost convert: error: {out}: cannot write: no space left on the device"
    assert list(folder.iterdir()) == []


def test_model_save_on_a_full_disk_leaves_nothing(inputs, mounted):
    from goniofrost.frost.model import FrostModel

    folder = mounted("size=64k")
    with pytest.raises(OutputError, match="no space left on the device"):
        FrostModel.load(inputs / "model").save(folder / "model")
    assert list(folder.iterdir()) == []
