"""The FROST model: the log-relative mapping and the PCA dictionary, stored on disk.

A model is a **directory**: ``model.json`` (format, grid, names, eps, content hash, noise,
calibration) and one ``.npy`` per array, rows in ``grid.valid_cells`` order::

    dictionary.npy        float32 (n_valid, K)   D = U S, the atoms
    singular_values.npy   float64 (K,)           S
    coefficients.npy      float64 (K, t)         V^T, a column per training column
    mean.npy              float32 (n_valid,)     mu, per-row mean of the mapped training data
    reference.npy         float32 (n_valid,)     r, per-row median of the weighted training data
    weight.npy            float32 (n_valid,)     w = clip(cos theta_i cos theta_o, 0.01, 1)
    noise_variance.npy    float32 (n_valid,)     sigma_c^2 (format 2, optional)

The mapping: ``L = log((w x + eps) / (r + eps))`` for x in 1/sr.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from goniofrost.core.atomic_file import check_output_dir, output_errors
from goniofrost.core.errors import GoniofrostError
from goniofrost.core.grid import MerlGrid

FORMAT = "goniofrost-frost-model"
VERSION = 2
READABLE_VERSIONS = (1, 2)
WEIGHT_CONVENTION = "clip(cos(theta_i) * cos(theta_o), 0.01, 1)"
ARRAYS = ("dictionary", "singular_values", "coefficients", "mean", "reference", "weight")
OPTIONAL_ARRAYS = ("noise_variance",)
META_FILE = "model.json"
HASH_CHUNK_BYTES = 1 << 24   # 16 MB of an array at a time: the hash and the finiteness check share the pass


class ModelError(GoniofrostError, ValueError):
    """A model directory that cannot be read (names the path, what was expected and found)."""


def check_model_destination(path) -> None:
    """Raise now (ModelError, OutputError) if a model could not be saved at ``path`` later: an
    existing path that is not a model directory, or a folder that cannot be written. Creates
    nothing (``train`` checks its --out before training)."""
    path = Path(path)
    if path.exists() and not (path.is_dir() and (path / META_FILE).is_file()):
        raise ModelError(f"{path}: exists and is not a model directory; refusing to overwrite")
    check_output_dir(path.parent)


@dataclass
class FrostModel:
    """A trained FROST model (mapping + PCA dictionary) over the valid cells of ``grid``.

    Attributes (n = grid.n_valid, K = number of components, t = 3 x number of materials):
        grid: the MERL grid the rows refer to (row i is cell ``grid.valid_cells[i]``).
        names: training material names (t / 3 of them; column c of ``coefficients`` is
            material ``names[c // 3]``, channel ``"RGB"[c % 3]``).
        eps: the offset of the log-relative map (0.001).
        dictionary: (n, K) float32, D = U S, atoms in the mapped domain.
        singular_values: (K,) float64, S (descending).
        coefficients: (K, t) float64, V^T: the training signals' coefficients.
        mean: (n,) float32, mu.
        reference: (n,) float32, r (weighted BRDF, 1/sr).
        weight: (n,) float32, w (dimensionless).
        noise_variance: (n,) float32 sigma_c^2, or None (scalar noise; see the module doc).
        noise: how the noise model was learned and the predicted-error calibration ({} if none).
        content_hash: hex BLAKE2b of the arrays and metadata (identifies the model).
    """

    grid: MerlGrid
    names: list[str]
    eps: float
    dictionary: np.ndarray
    singular_values: np.ndarray
    coefficients: np.ndarray
    mean: np.ndarray
    reference: np.ndarray
    weight: np.ndarray
    noise_variance: np.ndarray | None = None
    noise: dict = field(default_factory=dict)
    content_hash: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.content_hash:
            self.content_hash = self.compute_hash()

    # ----- sizes ----------------------------------------------------------------------
    @property
    def n_components(self) -> int:
        """K, the number of atoms kept."""
        return int(self.singular_values.shape[0])

    @property
    def n_signals(self) -> int:
        """t, the number of training columns (3 per material)."""
        return int(self.coefficients.shape[1])

    # ----- the mapping ----------------------------------------------------------------
    def to_log(self, values, positions=None) -> np.ndarray:
        """Map BRDF values (1/sr) to the log-relative domain; mu is NOT subtracted.

        values: (..., n, 3) with n = len(positions) (or n_valid when positions is None).
        positions: int (n,) indices into ``grid.valid_cells`` (rows of the model arrays).
        Returns float64 of the same shape: ``log((w x + eps) / (r + eps))``.
        """
        w, r = self._rows(positions)
        x = np.asarray(values, dtype=np.float64)
        return np.log(w[:, None] * x + self.eps) - np.log(r[:, None] + self.eps)

    def from_log(self, mapped, positions=None) -> np.ndarray:
        """Invert ``to_log`` (mu already added back); clamp to >= 0. Returns float64 1/sr.

        A mapped value beyond float64's range (above ~709) gives inf, without a warning:
        callers that write values check them (``reconstruct`` refuses such an estimate).
        """
        w, r = self._rows(positions)
        y = np.asarray(mapped, dtype=np.float64)
        with np.errstate(over="ignore"):
            x = (np.exp(y) * (r[:, None] + self.eps) - self.eps) / w[:, None]
        return np.maximum(x, 0.0)

    def _rows(self, positions) -> tuple[np.ndarray, np.ndarray]:
        if positions is None:
            return np.asarray(self.weight, np.float64), np.asarray(self.reference, np.float64)
        positions = np.asarray(positions, dtype=np.int64)
        return (np.asarray(self.weight[positions], np.float64),
                np.asarray(self.reference[positions], np.float64))

    # ----- identity -------------------------------------------------------------------
    def metadata(self) -> dict:
        """The JSON part of the model (everything but the arrays)."""
        return {
            "format": FORMAT, "version": VERSION, "grid": self.grid.as_dict(),
            "names": list(self.names), "eps": float(self.eps), "weight": WEIGHT_CONVENTION,
            "n_valid": int(self.grid.n_valid), "n_components": self.n_components,
            "n_signals": self.n_signals, "noise": self.noise, "info": self.info,
        }

    def compute_hash(self) -> str:
        """Hex BLAKE2b (32 bytes) over the metadata and every array's bytes."""
        return self._digest()

    def _digest(self, check=None) -> str:
        """``compute_hash``, reading each array in row chunks of about HASH_CHUNK_BYTES;
        ``check(name, start, chunk)`` is called on every chunk (``load``'s finiteness check: one
        pass over a memory-mapped file, no copy of the whole array)."""
        h = hashlib.blake2b(digest_size=32)
        meta = {k: v for k, v in self.metadata().items() if k != "info"}
        h.update(json.dumps(meta, sort_keys=True).encode())
        for name in self._present_arrays():
            arr = getattr(self, name)
            h.update(f"{name}:{arr.dtype.str}:{arr.shape}".encode())
            rows = max(1, HASH_CHUNK_BYTES // max(1, arr.itemsize * int(np.prod(arr.shape[1:]))))
            for start in range(0, len(arr), rows):
                chunk = np.ascontiguousarray(arr[start:start + rows])
                h.update(memoryview(chunk).cast("B"))
                if check is not None:
                    check(name, start, chunk)
        return h.hexdigest()

    def _present_arrays(self) -> tuple[str, ...]:
        return ARRAYS + tuple(name for name in OPTIONAL_ARRAYS if getattr(self, name) is not None)

    # ----- files ----------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the model directory ``path`` atomically (temporary sibling, then rename).

        An existing model directory at ``path`` is replaced; any other existing path is refused.
        """
        path = Path(path)
        check_model_destination(path)
        with output_errors(path):
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
            try:
                self._write_into(tmp)
                if path.exists():
                    shutil.rmtree(path)
                os.replace(tmp, path)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
        return path

    def _write_into(self, folder: Path) -> None:
        for name in self._present_arrays():
            np.save(folder / f"{name}.npy", np.ascontiguousarray(getattr(self, name)))
        meta = self.metadata() | {"content_hash": self.content_hash}
        (folder / META_FILE).write_text(json.dumps(meta, indent=1))

    @classmethod
    def load(cls, path, mmap: bool = True) -> "FrostModel":
        """Open a model directory; arrays are memory-mapped read-only when ``mmap``."""
        path = Path(path)
        meta = _read_meta(path)
        arrays = {}
        optional = tuple(n for n in OPTIONAL_ARRAYS if (path / f"{n}.npy").is_file()) if meta["version"] >= 2 else ()
        for name in ARRAYS + optional:
            file = path / f"{name}.npy"
            try:
                arrays[name] = np.load(file, mmap_mode="r" if mmap else None, allow_pickle=False)
            except (OSError, ValueError) as exc:
                raise ModelError(f"{file}: cannot read model array ({exc})") from exc
        grid = MerlGrid(**meta["grid"])
        model = cls(grid=grid, names=list(meta["names"]), eps=float(meta["eps"]),
                    content_hash=str(meta["content_hash"]), info=meta.get("info", {}),
                    noise=meta.get("noise") or {}, **arrays)
        _check_shapes(path, model, meta)
        _check_content(path, model, meta)
        return model


def _read_meta(path: Path) -> dict:
    file = path / META_FILE
    if not file.is_file():
        raise ModelError(f"{path}: not a goniofrost model (expected a directory with {META_FILE})")
    try:
        meta = json.loads(file.read_text())
    except (OSError, ValueError) as exc:
        raise ModelError(f"{file}: not valid JSON ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ModelError(f"{file}: expected format {FORMAT!r}, found {meta.get('format') if isinstance(meta, dict) else meta!r}")
    missing = [k for k in ("grid", "names", "eps", "content_hash") if k not in meta]
    if missing:
        raise ModelError(f"{file}: missing fields {missing}")
    # a hand-edited or damaged model.json: each field's type, named, instead of a TypeError deep in load
    grid, names = meta["grid"], meta["names"]
    if not (isinstance(grid, dict) and set(grid) == {"n_th", "n_td", "n_pd"}
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in grid.values())):
        raise ModelError(f"{file}: grid: expected {{\"n_th\": int, \"n_td\": int, \"n_pd\": int}} (positive), "
                         f"found {grid!r}")
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise ModelError(f"{file}: names: expected a list of material names, found {names!r}")
    if not (isinstance(meta["eps"], (int, float)) and not isinstance(meta["eps"], bool) and 0 <= meta["eps"] < math.inf):
        raise ModelError(f"{file}: eps: expected a finite number >= 0, found {meta['eps']!r}")
    for key in ("info", "noise"):
        if meta.get(key) is not None and not isinstance(meta[key], dict):
            raise ModelError(f"{file}: {key}: expected a JSON object, found {meta[key]!r}")
    meta.setdefault("version", 1)
    if meta["version"] not in READABLE_VERSIONS:
        raise ModelError(f"{file}: version: expected one of {list(READABLE_VERSIONS)}, found {meta['version']!r} "
                         "(a model written by a newer goniofrost)")
    return meta


def _check_content(path: Path, model: FrostModel, meta: dict) -> None:
    """Every array finite, and (format 2) the content hash model.json records that of the files
    (docs/decisions/0500-model-load-checks.md)."""
    def finite(name, start, chunk):
        bad = np.argwhere(~np.isfinite(chunk))
        if bad.size:
            index = (start + int(bad[0][0]),) + tuple(int(i) for i in bad[0][1:])
            raise ModelError(f"{path / (name + '.npy')}: element {list(index)} is {chunk[tuple(bad[0])]!s}; expected "
                             "finite numbers (a damaged model file: train the model again)")

    found = model._digest(finite)
    if meta["version"] >= 2 and found != model.content_hash:  # format 1 hashed other metadata
        raise ModelError(f"{path / META_FILE}: content_hash: expected {found[:16]}... (the hash of the model's files), "
                         f"found {model.content_hash[:16]}... (a file of the model was changed after training: "
                         "train the model again)")


def _check_shapes(path: Path, model: FrostModel, meta: dict) -> None:
    n, k, t = model.grid.n_valid, meta.get("n_components"), meta.get("n_signals")
    expected = {"dictionary": (n, k), "singular_values": (k,), "coefficients": (k, t),
                "mean": (n,), "reference": (n,), "weight": (n,), "noise_variance": (n,)}
    for name, shape in expected.items():
        if getattr(model, name) is None:
            continue
        found = getattr(model, name).shape
        if found != shape:
            raise ModelError(f"{path / (name + '.npy')}: shape {found}, expected {shape}")
    if t != 3 * len(model.names):
        raise ModelError(f"{path / META_FILE}: {t} signals but {len(model.names)} names (expected 3 per name)")
