"""MERL .binary reader and writer (DESIGN.md, "MERL .binary format")."""
from __future__ import annotations

import numpy as np
import pytest

from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid
from goniofrost.brdf.merl_file import MerlFileError, RGB_SCALE, expected_size, read_merl, write_merl

GRID = MerlGrid(30, 30, 60)
SCALE = np.array([1 / 1500, 1.15 / 1500, 1.66 / 1500])


def hand_made_file(path, stored: np.ndarray, header=(30, 30, 60)) -> None:
    """The documented layout written by hand: int32 header, then the R, G and B blocks."""
    with open(path, "wb") as handle:
        np.asarray(header, dtype="<i4").tofile(handle)
        np.asarray(stored, dtype="<f8").T.tofile(handle)  # (3, n): R block, G block, B block


def random_brdf(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    brdf = rng.lognormal(-1.0, 2.0, size=(GRID.size, 3))
    brdf[~GRID.valid_mask] = np.nan
    return brdf


def test_scale_is_the_design_scale():
    np.testing.assert_array_equal(RGB_SCALE, SCALE)
    assert expected_size(GRID) == 12 + 3 * 54_000 * 8


def test_hand_made_file_reads_as_stored_times_scale(tmp_path):
    stored = np.random.default_rng(1).uniform(0, 3000, size=(GRID.size, 3))
    stored[5] = [-1.0, -0.5, -1e-300]  # every negative value is missing
    hand_made_file(tmp_path / "m.binary", stored)
    brdf = read_merl(tmp_path / "m.binary")
    assert brdf.shape == (GRID.size, 3) and brdf.dtype == np.float64
    assert np.all(np.isnan(brdf[5]))
    keep = np.arange(GRID.size) != 5
    np.testing.assert_array_equal(brdf[keep], stored[keep] * SCALE)


def test_written_file_has_the_documented_bytes(tmp_path):
    brdf = random_brdf()
    write_merl(tmp_path / "m.binary", brdf, GRID)
    raw = (tmp_path / "m.binary").read_bytes()
    assert len(raw) == expected_size(GRID)
    assert np.frombuffer(raw[:12], "<i4").tolist() == [30, 30, 60]
    stored = np.frombuffer(raw[12:], "<f8").reshape(3, GRID.size).T
    assert np.all(stored[~GRID.valid_mask] == -1.0)  # NaN is written as exactly -1
    np.testing.assert_array_equal(stored[GRID.valid_mask], brdf[GRID.valid_mask] / SCALE)


def test_round_trips_are_bit_exact(tmp_path):
    # write -> read -> write gives identical bytes; read -> write -> read gives identical values.
    # (A float64 x scale / scale is not always x, so an arbitrary file's bytes cannot survive
    # read -> write; values that have been through a file once do, bit for bit.)
    write_merl(tmp_path / "a.binary", random_brdf(2), GRID)
    first = read_merl(tmp_path / "a.binary")
    write_merl(tmp_path / "b.binary", first, GRID)
    assert (tmp_path / "a.binary").read_bytes() == (tmp_path / "b.binary").read_bytes()
    second = read_merl(tmp_path / "b.binary")
    assert np.array_equal(first, second, equal_nan=True)
    assert np.array_equal(np.isnan(first).any(1), ~GRID.valid_mask)


def test_grid_is_taken_from_the_header_and_can_be_required(tmp_path):
    write_merl(tmp_path / "m.binary", random_brdf(), GRID)
    assert read_merl(tmp_path / "m.binary").shape == (GRID.size, 3)
    with pytest.raises(MerlFileError) as err:
        read_merl(tmp_path / "m.binary", grid=MerlGrid())
    assert str(err.value) == f"{tmp_path / 'm.binary'}: header gives resolutions (30, 30, 60), expected (90, 90, 180)"


@pytest.mark.parametrize("header", [(0, 90, 180), (90, -1, 180), (1_000_000, 90, 180)])
def test_wrong_header_is_refused(tmp_path, header):
    path = tmp_path / "bad.binary"
    hand_made_file(path, np.zeros((GRID.size, 3)), header=header)
    with pytest.raises(MerlFileError) as err:
        read_merl(path)
    assert str(err.value).startswith(f"{path}: wrong MERL header {header}, expected three positive")
    assert isinstance(err.value, GoniofrostError)


def test_an_rgl_tensor_file_is_named_as_one(tmp_path):
    """compare brdf.bsdf said 'wrong MERL header (1936614772, ...)': the tensor file's magic read as int32."""
    path = tmp_path / "brdf.bsdf"
    path.write_bytes(b"tensor_file\x00" + bytes(64))
    with pytest.raises(MerlFileError) as err:
        read_merl(path)
    assert str(err.value) == (f"{path}: an RGL tensor file (the .bsdf of goniofrost export, Mitsuba's 'measured' "
                              f"BSDF), not a MERL .binary: give the brdf.binary it was exported from")


@pytest.mark.parametrize("delta, kind", [(-8, "truncated"), (-1, "truncated"), (8, "oversized"), (1, "oversized")])
def test_truncated_or_oversized_file_names_both_sizes(tmp_path, delta, kind):
    path = tmp_path / "m.binary"
    write_merl(path, random_brdf(), GRID)
    raw = path.read_bytes()
    path.write_bytes(raw[:delta] if delta < 0 else raw + b"\0" * delta)
    want = expected_size(GRID)
    with pytest.raises(MerlFileError) as err:
        read_merl(path)
    assert str(err.value).startswith(
        f"{path}: {kind} MERL file: {want + delta} bytes, expected {want} bytes for a (30, 30, 60) grid")


def test_file_shorter_than_its_header_and_missing_file(tmp_path):
    path = tmp_path / "short.binary"
    path.write_bytes(b"\x5a\0\0\0\x5a\0")
    with pytest.raises(MerlFileError, match=r"short\.binary: truncated MERL file: 6 bytes, expected at least a 12-byte header"):
        read_merl(path)
    with pytest.raises(MerlFileError, match=r"absent\.binary: no such file"):
        read_merl(tmp_path / "absent.binary")


def test_writer_refuses_bad_values_and_leaves_no_file(tmp_path):
    brdf = random_brdf()
    for bad_value, message in ((-0.1, "negative BRDF values"), (np.inf, "1 infinite values")):
        bad = brdf.copy()
        bad[np.flatnonzero(GRID.valid_mask)[0], 1] = bad_value
        with pytest.raises(MerlFileError, match=rf"write_merl: {message}.*m\.binary"):  # a GoniofrostError: the CLI reports it
            write_merl(tmp_path / "m.binary", bad, GRID)
    with pytest.raises(MerlFileError, match=r"shape \(54000, 3\)"):
        write_merl(tmp_path / "m.binary", brdf[:-1], GRID)
    assert list(tmp_path.iterdir()) == []
