"""Render the preview spheres with Mitsuba 3 from an exported RGL tensor file.

The picture of ``preview.render_set`` (orthographic unit sphere, the same directional lights, one
unjittered sample per pixel) in the same HDR units, so the two compare pixel for pixel. A spectral
file renders in SPECTRAL_VARIANT; with ``spp`` > 1 it uses the independent sampler. Needs
``mitsuba`` (``pip install goniofrost[render]``).
"""
from __future__ import annotations

import numpy as np

from goniofrost.brdf.preview import DEFAULT_LIGHTS
from goniofrost.core.errors import GoniofrostError

VARIANT = "scalar_rgb"  # the exported file is RGB: an RGB variant; scalar runs everywhere
SPECTRAL_VARIANT = "scalar_spectral"  # the spectral file (rgl-spectral): Mitsuba's spectral variants only


class MitsubaMissingError(GoniofrostError, ImportError):
    """Mitsuba 3 is not installed (it is the optional 'render' extra)."""


def load_mitsuba(variant: str = VARIANT):
    """The ``mitsuba`` module with ``variant`` set (RGB by default); a clear error when it is not
    installed, or when a ``llvm_*`` variant finds no LLVM it can run on (``drjit_llvm``)."""
    from goniofrost.brdf.drjit_llvm import name_newest_llvm

    try:
        import mitsuba as mi
    except ImportError:
        raise MitsubaMissingError("rendering with Mitsuba needs Mitsuba 3: pip install 'goniofrost[render]' "
                                  "(or pip install mitsuba)") from None
    if variant.startswith("llvm_"):
        try:
            name_newest_llvm(variant)  # before the variant starts Dr.Jit's LLVM backend
        except RuntimeError as exc:
            raise MitsubaMissingError(str(exc)) from None
    mi.set_variant(variant)
    return mi


_PLUGINS: set[tuple[str, str]] = set()


def load_with_bsdf(variant: str, name: str, make_class):
    """``load_mitsuba(variant)`` with the Python BSDF plugin ``name`` registered (once per process
    and variant: Mitsuba keeps a registered plugin); ``make_class(mi)`` -> the plugin's class."""
    mi = load_mitsuba(variant)
    if (variant, name) not in _PLUGINS:
        mi.register_bsdf(name, lambda props: make_class(mi)(props))
        _PLUGINS.add((variant, name))
    return mi


def scene_dict(bsdf_path, light, size: int, spp: int = 1) -> dict:
    """The Mitsuba scene of one preview sphere lit by ``light`` = (direction to the light, irradiance)."""
    direction, irradiance = light
    to_light = np.asarray(direction, dtype=np.float64)
    to_light = to_light / np.linalg.norm(to_light)
    return {
        "type": "scene",
        "integrator": {"type": "direct"},
        "sensor": {
            "type": "orthographic",
            "to_world": _look_along_minus_z(),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": ({"type": "stratified", "sample_count": 1, "jitter": False} if spp == 1 else
                        {"type": "independent", "sample_count": spp}),
        },
        "sphere": {"type": "sphere", "bsdf": {"type": "measured", "filename": str(bsdf_path)}},
        "light": {"type": "directional", "direction": (-to_light).tolist(),
                  "irradiance": {"type": "rgb", "value": [float(irradiance)] * 3}},
    }


def _look_along_minus_z():
    import mitsuba as mi  # the caller has set the variant

    return mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0])


def render_set_mitsuba(bsdf_path, lights=DEFAULT_LIGHTS, size: int = 192, variant: str = VARIANT,
                       spp: int = 1) -> np.ndarray:
    """HDR images (n_lights, size, size, 3) of the sphere under each light, rendered by Mitsuba.

    ``variant``: VARIANT for an RGB file, SPECTRAL_VARIANT for a spectral one; ``spp`` > 1: the
    independent sampler (module docstring), seed 0.
    """
    mi = load_mitsuba(variant)
    images = []
    for _, direction, irradiance in lights:
        scene = mi.load_dict(scene_dict(bsdf_path, (direction, irradiance), size, spp))
        images.append(np.array(mi.render(scene, spp=spp, seed=0), dtype=np.float64))
    return np.stack(images)


def make_preview_mitsuba(estimate_path, reference_path=None, lights=DEFAULT_LIGHTS, size: int = 192):
    """``preview.make_preview`` rendered by Mitsuba: each MERL file exported (temporary .bsdf), then rendered."""
    import tempfile
    from pathlib import Path

    from goniofrost.brdf.mitsuba_export import export_binary_file
    from goniofrost.brdf.preview import Preview, rendering_snr_db

    load_mitsuba()  # fail before exporting anything
    with tempfile.TemporaryDirectory(prefix="goniofrost-preview-") as folder:
        images = []
        for k, path in enumerate(p for p in (estimate_path, reference_path) if p is not None):
            bsdf = Path(folder) / f"{k}.bsdf"
            export_binary_file(path, bsdf)
            images.append(render_set_mitsuba(bsdf, lights, size))
    reference = images[1] if len(images) > 1 else None
    snr = None if reference is None else rendering_snr_db(reference, images[0])
    return Preview(images[0], reference, snr, tuple(name for name, _, _ in lights))
