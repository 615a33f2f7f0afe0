"""Scene-aware against scene-blind Bayesian design: the error of the rendered scene, and of the whole BRDF.

For each shipped scene (config/scenes) and m, a test material is "measured" at the design's cells
(exact values of the material: the design is what is compared), reconstructed by the posterior
mean, exported as an RGL tensor and rendered by Mitsuba 3 in that scene; the same scene rendered
with the true material (same seed, same spp) is the reference. Reported per scene and m, as the
median over the test materials: the image's relative MSE and PSNR, the scene-seen error (the
log-relative MSE weighted by the scene's usage map: what the design minimises) and the
whole-BRDF log-relative MSE, for the scene-blind design (``plan``) and the scene-aware one
(``plan --usage``). Test materials are fixed before any result: every 7th material of the
combined, sorted shared library starting at the 4th; the model is trained on the others only.

    .venv/bin/python benchmarks/scene_design.py --out /tmp/scene-bench            # full size
    .venv/bin/python benchmarks/scene_design.py --smallest --out /tmp/scene-small  # what the test runs

Prints the table; writes results.json (every row) and, per scene, a picture of the truth and both
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


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--m", type=int, nargs="+", default=[10, 20, 40])
    p.add_argument("--materials", type=int, default=None, help="use only the first N test materials")
    p.add_argument("--spp", type=int, default=64, help="samples per pixel of the renders")
    p.add_argument("--usage-spp", type=int, default=16, help="samples per pixel of the usage recording")
    p.add_argument("--scenes", nargs="+", choices=SCENES, default=list(SCENES))
    p.add_argument("--smallest", action="store_true",
                   help="the built-in library on a 30 x 30 x 60 grid, 1 test material, m = 4, 4 spp (a test runs it)")
    return p.parse_args(argv)


def setting(args):
    """(dataset specs, grid, test names, m list, spp, usage spp)."""
    from goniofrost.bench.data import material_names
    from goniofrost.core.grid import FULL_GRID, MerlGrid

    if args.smallest:
        specs, grid, ms, spp, uspp = ["builtin"], MerlGrid(30, 30, 60), [4], 4, 2
        names = sorted(n for _, n in material_names(specs))[:12]
    else:
        specs = [f"nbrdf:{SHARED / 'nbrdf_merl.npz'}", f"nbrdf:{SHARED / 'nbrdf_rgl.npz'}"]
        grid, ms, spp, uspp = FULL_GRID, args.m, args.spp, args.usage_spp
        names = sorted(n for _, n in material_names(specs))
    test = names[3::7]
    if args.smallest:
        test = test[:1]
    if args.materials is not None:
        test = test[:args.materials]
    return specs, grid, names, test, ms, spp, uspp


def image_errors(image: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(relative MSE, PSNR in dB against the truth's peak) of two (H, W, 3) renders."""
    err = float(np.mean((image - truth) ** 2))
    rel = err / float(np.mean(truth ** 2))
    peak = float(np.max(truth))
    return rel, 10.0 * np.log10(peak * peak / err) if err > 0 else float("inf")


def main(argv=None) -> int:
    from goniofrost.brdf.mitsuba_export import export_mitsuba
    from goniofrost.brdf.mitsuba_usage import record_usage, render_with_bsdf
    from goniofrost.datasets.tabulate import collect_materials, tabulate_materials
    from goniofrost.frost.bayes_selection import select_bayes
    from goniofrost.frost.metrics import log_relative_mse
    from goniofrost.frost.reconstruction import reconstruct_bayes
    from goniofrost.frost.training import train

    args = parse(argv)
    specs, grid, names, test, ms, spp, uspp = setting(args)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    training = [n for n in names if n not in test]
    model = train(specs, only=training, grid=grid, cache=True)
    print(f"model: {len(training)} training materials, K = {model.n_components} ({time.perf_counter() - t0:.0f} s); "
          f"{len(test)} test materials: {', '.join(test)}", flush=True)
    scenes = {s: REPO / "config" / "scenes" / f"{s}.xml" for s in args.scenes}
    usage = {s: record_usage(path, "sample", spp=uspp, grid=grid)[0] for s, path in scenes.items()}
    m_max = max(ms)
    designs = {"blind": select_bayes(model, m_max).positions}
    designs |= {s: select_bayes(model, m_max, usage=usage[s]).positions for s in scenes}
    truths = tabulate_materials(collect_materials(specs, only=test), grid)
    weight = np.asarray(model.weight, dtype=np.float64)[:, None]
    rows, pictures = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for k, name in enumerate(test):
            truth = np.asarray(truths[k], dtype=np.float64)
            full = np.full((grid.size, 3), np.nan)
            full[grid.valid_cells] = truth
            export_mitsuba(Path(tmp) / "truth.bsdf", full, grid, source=name)
            reference = {s: render_with_bsdf(path, "sample", Path(tmp) / "truth.bsdf", spp) for s, path in scenes.items()}
            for m in ms:
                for design, rows_picked in designs.items():
                    positions = rows_picked[:m]
                    rec = reconstruct_bayes(model, positions, truth[positions], with_std=False)
                    whole = log_relative_mse(model, truth, rec.brdf)
                    diff = (np.log(weight * truth + model.eps) - np.log(weight * np.maximum(rec.brdf, 0) + model.eps)) ** 2
                    full[grid.valid_cells] = rec.brdf
                    export_mitsuba(Path(tmp) / "rec.bsdf", full, grid, source=f"{name} {design} m={m}")
                    for s, path in scenes.items():
                        if design not in ("blind", s):
                            continue
                        image = render_with_bsdf(path, "sample", Path(tmp) / "rec.bsdf", spp)
                        rel, psnr = image_errors(image, reference[s])
                        rows.append({"material": name, "scene": s, "m": m, "design": "aware" if design == s else "blind",
                                     "image_rel_mse": rel, "psnr_db": psnr, "brdf_log_mse": whole,
                                     "seen_log_mse": float(usage[s] @ diff.mean(1))})
                        if k == 0 and m == ms[len(ms) // 2]:
                            pictures[(s, rows[-1]["design"])] = image
                            pictures[(s, "truth")] = reference[s]
            print(f"{k + 1}/{len(test)} {name} ({time.perf_counter() - t0:.0f} s)", flush=True)
    (args.out / "results.json").write_text(json.dumps({"test": test, "spp": spp, "usage_spp": uspp, "m": ms,
                                                       "grid": grid.as_dict(), "rows": rows}, indent=1))
    print(table(rows, ms))
    save_pictures(pictures, args.out)
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


def table(rows: list[dict], ms: list[int]) -> str:
    """Median over materials per scene and m: image rel. MSE and PSNR, whole-BRDF error, both designs."""
    lines = ["| scene | m | image rel. MSE blind | aware | change | PSNR blind | aware (dB) | seen log-MSE blind | aware "
             "| whole BRDF log-MSE blind | aware |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in SCENES:
        for m in ms:  # scenes not run have no rows
            pick = {d: [r for r in rows if r["scene"] == s and r["m"] == m and r["design"] == d] for d in ("blind", "aware")}
            if not pick["blind"]:
                continue
            med = {d: {k: float(np.median([r[k] for r in v]))
                       for k in ("image_rel_mse", "psnr_db", "seen_log_mse", "brdf_log_mse")} for d, v in pick.items()}
            change = 100.0 * (med["aware"]["image_rel_mse"] / med["blind"]["image_rel_mse"] - 1.0)
            lines.append(f"| {s} | {m} | {med['blind']['image_rel_mse']:.4g} | {med['aware']['image_rel_mse']:.4g} | "
                         f"{change:+.0f} % | {med['blind']['psnr_db']:.1f} | {med['aware']['psnr_db']:.1f} | "
                         f"{med['blind']['seen_log_mse']:.4f} | {med['aware']['seen_log_mse']:.4f} | "
                         f"{med['blind']['brdf_log_mse']:.4f} | {med['aware']['brdf_log_mse']:.4f} |")
    return "\n".join(lines)


def save_pictures(pictures: dict, out: Path) -> None:
    """One PNG per scene: truth | scene-blind | scene-aware, tone-mapped alike."""
    import cv2

    for s in SCENES:
        if (s, "truth") not in pictures:
            continue
        panels = [pictures[(s, k)] for k in ("truth", "blind", "aware")]
        top = float(np.percentile(panels[0], 99.5)) or 1.0
        strip = np.concatenate([np.clip(p / top, 0, 1) ** (1 / 2.2) for p in panels], axis=1)
        image = (strip * 255).astype(np.uint8)[..., ::-1]
        image = cv2.resize(image, (image.shape[1] * 3, image.shape[0] * 3), interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(out / f"{s}.png"), image)


if __name__ == "__main__":
    sys.exit(main())
