"""Record how a Mitsuba 3 scene uses one object's BSDF: the (w_i, w_o) pairs the renderer visits.

The object's BSDF is wrapped in ``goniofrost_recorder`` (a Python plugin, ``scalar_rgb``) that
keeps each evaluation's directions and each BSDF sample whose ray reaches a light.
``render_with_bsdf`` renders the scene with the object's BSDF replaced. Why:
docs/explanations/scene-aware-design.md. Needs ``mitsuba``.
"""
from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from goniofrost.brdf.usage import UsageError, fold_pairs
from goniofrost.core.grid import FULL_GRID, MerlGrid

VARIANT = "scalar_rgb"
RECORDER = "goniofrost_recorder"


def _mitsuba():
    """Mitsuba with the scalar RGB variant set and the recording BSDF registered."""
    from goniofrost.brdf.mitsuba_render import load_with_bsdf

    return load_with_bsdf(VARIANT, RECORDER, _recorder_class)


def _recorder_class(mi):
    """The recording BSDF class of the active variant (defined once the variant is set)."""

    class Recorder(mi.BSDF):
        """Forwards every call to ``inner`` (default: a diffuse BSDF) and records the directions."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.inner = props["inner"] if "inner" in props else mi.load_dict({"type": "diffuse"})
            self.m_flags = self.inner.flags()
            self.m_components = [self.inner.flags(i) for i in range(self.inner.component_count())]
            # (wi xyz, wo xyz), wi towards the previous vertex, wo towards the light: evaluations
            # (emitter sampling, MIS) and BSDF samples
            self.pairs: list[tuple] = []
            self.sampled: list[tuple] = []
            self.scene = None  # set once the scene is loaded: a sample is kept when its ray reaches light

        def sample(self, ctx, si, sample1, sample2, active=True):
            bs, weight = self.inner.sample(ctx, si, sample1, sample2, active)
            if bs.pdf > 0 and self._reaches_light(si, bs.wo):
                self.sampled.append((*si.wi, *bs.wo))
            return bs, weight

        def _reaches_light(self, si, wo) -> bool:
            """True when the ray from ``si`` along the local direction ``wo`` hits an emitting
            shape, or escapes a scene that has an environment emitter (the sky)."""
            if self.scene is None:
                return True
            hit = self.scene.ray_intersect(si.spawn_ray(si.to_world(wo)))
            if hit.is_valid():
                return hit.shape.emitter() is not None
            return self.scene.environment() is not None

        def eval(self, ctx, si, wo, active=True):
            self.pairs.append((*si.wi, *wo))
            return self.inner.eval(ctx, si, wo, active)

        def pdf(self, ctx, si, wo, active=True):
            return self.inner.pdf(ctx, si, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            self.pairs.append((*si.wi, *wo))
            return self.inner.eval_pdf(ctx, si, wo, active)

        def traverse(self, callback):
            pass

        def to_string(self):
            return f"{RECORDER}[{self.inner}]"

    return Recorder


# ----- the scene file ---------------------------------------------------------------------------------
def _read_scene(scene_path) -> ET.ElementTree:
    path = Path(scene_path)
    try:
        return ET.parse(path)
    except FileNotFoundError:
        raise UsageError(f"{path}: scene file not found") from None
    except (OSError, ET.ParseError) as exc:
        raise UsageError(f"{path}: not a Mitsuba scene (XML): {exc}") from None


def _object(tree: ET.ElementTree, object_id: str, scene_path) -> ET.Element:
    """The ``<shape id=object_id>`` element; UsageError listing the shapes' ids when there is none."""
    shapes = list(tree.getroot().iter("shape"))
    for shape in shapes:
        if shape.get("id") == object_id:
            return shape
    ids = [s.get("id") for s in shapes if s.get("id")]
    raise UsageError(f"{scene_path}: no shape with id {object_id!r} (shapes with an id: {', '.join(ids) or 'none'})")


def _replace_bsdf(shape: ET.Element, replacement: ET.Element, keep_inner: bool) -> None:
    """Put ``replacement`` in place of the shape's BSDF (a nested ``<bsdf>`` or a ``<ref>``); with
    ``keep_inner`` the old one becomes its ``inner`` property."""
    old = next((child for child in shape if child.tag in ("bsdf", "ref")), None)
    if old is not None:
        shape.remove(old)
        if keep_inner:
            inner = copy.deepcopy(old)
            inner.set("name", "inner")
            replacement.append(inner)
    shape.append(replacement)


def load_scene(scene_path, object_id: str, bsdf: ET.Element, keep_inner: bool = False, mi=None):
    """The Mitsuba scene with the object's BSDF replaced by ``bsdf``; UsageError when it cannot load.
    ``mi``: the mitsuba module with the variant to load in (default: this module's scalar RGB)."""
    mi = _mitsuba() if mi is None else mi
    tree = _read_scene(scene_path)
    _replace_bsdf(_object(tree, object_id, scene_path), bsdf, keep_inner)
    resolver = mi.file_resolver()
    resolver.prepend(str(Path(scene_path).resolve().parent))  # meshes and textures relative to the scene
    try:
        return mi.load_string(ET.tostring(tree.getroot(), encoding="unicode"))
    except Exception as exc:  # noqa: BLE001 - Mitsuba raises RuntimeError with a long message
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UsageError(f"{scene_path}: Mitsuba cannot load the scene: {first}") from None


def _find_shape(scene, object_id: str):
    return next(shape for shape in scene.shapes() if shape.id() == object_id)


# ----- recording and rendering ---------------------------------------------------------------------
def record_usage(scene_path, object_id: str, spp: int | None = None, grid: MerlGrid = FULL_GRID,
                 passes: int = 8, progress=None) -> tuple[np.ndarray, int]:
    """Render the scene with the object's BSDF recorded; return (usage map (n_valid,) float64, pairs).

    ``spp``: samples per pixel (default: the scene's sampler); rendered in ``passes`` passes of
    different seeds so that ``progress(done, total)`` can follow a long render.
    """
    mi = _mitsuba()
    scene = load_scene(scene_path, object_id, ET.Element("bsdf", {"type": RECORDER}), keep_inner=True)
    recorder = _find_shape(scene, object_id).bsdf()
    recorder.scene = scene
    total = int(spp) if spp is not None else int(scene.sensors()[0].sampler().sample_count())
    chunks = [c for c in np.diff(np.linspace(0, total, min(passes, total) + 1).round().astype(int)) if c > 0]
    for k, chunk in enumerate(chunks):
        mi.render(scene, seed=k, spp=int(chunk))
        if progress is not None:
            progress(k + 1, len(chunks))
    pairs = recorder.pairs
    if not all(mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta) for emitter in scene.emitters()):
        pairs = pairs + recorder.sampled  # a BSDF-sampled ray can find an area light or the sky
    pairs = np.asarray(pairs, dtype=np.float64).reshape(-1, 6)
    return fold_pairs(grid, pairs[:, :3], pairs[:, 3:]), len(pairs)


def render_with_bsdf(scene_path, object_id: str, bsdf_file, spp: int, seed: int = 0) -> np.ndarray:
    """The scene rendered with the object's BSDF replaced by the RGL tensor file ``bsdf_file``
    (Mitsuba's ``measured`` BSDF): float32 (H, W, 3) linear RGB."""
    mi = _mitsuba()
    measured = ET.Element("bsdf", {"type": "measured"})
    ET.SubElement(measured, "string", {"name": "filename", "value": str(Path(bsdf_file).resolve())})
    scene = load_scene(scene_path, object_id, measured)
    return np.asarray(mi.render(scene, seed=seed, spp=int(spp)), dtype=np.float32)[..., :3]
