"""Coverage of `runout invert --engine mpm-ad --uncertainty`: how often the 90 % intervals hold
the true strengths, over synthetic targets of the small dam with noise added to the deposit.

The dam is examples/small_dam.toml (10 m cells, 336 moving points, 160 frames). Its MPM run at
its own strengths (c of the lower downstream shell 40 kPa, phi of the upper one 41 degrees) is
observed at its last frame; each target adds independent Gaussian noise of --noise m to every
coordinate of every point (seed k for target k): the position error of a survey of the deposit,
the only error the intervals assume. Each target is back-calculated from (30 kPa, 36 degrees) in
[20, 60] kPa x [30, 45] degrees with `runout.inverse.invert(engine="mpm-ad", uncertainty=True)`,
the same call as the command. Reported: how many of the targets' intervals hold the truth, per
parameter, both at once, and inside the joint 90 % confidence ellipse
(θ̂ − θ)ᵀ Σ⁻¹ (θ̂ − θ) <= P F_{P, n − P}(0.9); the mean interval width against the scatter of the
estimates over the targets; the wall time.

    .venv/bin/python bench/invert_coverage.py [--targets 20] [--noise 0.5] [--threads 1]
                                              [--confidence 0.9] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.stats
import torch

from runout.inverse import invert
from runout.mpm import simulate
from runout.scene import load_scene, save_scene
from runout.trajectory import Trajectory, save_trajectory

REPO = Path(__file__).resolve().parents[1]
TRUTH = (40.0, 41.0)  # c of m1_downstream_lower (kPa), phi of m3_downstream_upper (degrees): the scene's
SPEC = """scene = "scene.toml"
[target]
trajectory = "target_{k:02d}"
frames = [{frame}]
[parameters.m1_downstream_lower]
c = {{ initial = 30.0, lower = 20.0, upper = 60.0 }}
[parameters.m3_downstream_upper]
phi = {{ initial = 36.0, lower = 30.0, upper = 45.0 }}
[optimiser]
max_iterations = 30
max_evaluations = 40
gtol = 1e-3
"""  # gtol: on this dam the normalised gradient has a floor of ~2e-4 near the minimum (the MPM's fine-scale
# roughness), so a tighter gtol only spends evaluations in line searches; 1e-3 is ~0.01 standard errors away


def one_target(folder: Path, k: int, exact: Trajectory, frame: int, noise: float, confidence: float) -> dict:
    """Back-calculate target k (the exact run, its deposit at `frame` moved by noise of seed k) with intervals."""
    positions = exact.positions.copy()
    positions[frame] += np.random.default_rng(k).normal(0.0, noise, positions[frame].shape).astype(positions.dtype)
    save_trajectory(replace(exact, positions=positions), folder / f"target_{k:02d}")
    spec = folder / f"spec_{k:02d}.toml"
    spec.write_text(SPEC.format(k=k, frame=frame))
    start = time.perf_counter()
    result = invert(spec, folder / f"out_{k:02d}", engine="mpm-ad", uncertainty=True, confidence=confidence)
    wall = time.perf_counter() - start
    iv = result.intervals
    truth = np.array(TRUTH)
    held = (iv.lower <= truth) & (truth <= iv.upper)
    error = iv.estimate - truth
    distance = float(error @ np.linalg.solve(iv.covariance, error))  # squared Mahalanobis
    ellipse = len(truth) * scipy.stats.f.ppf(confidence, len(truth), iv.degrees_of_freedom)
    return {"target": k, "estimate": iv.estimate.tolist(), "standard_error": iv.standard_error.tolist(),
            "lower": iv.lower.tolist(), "upper": iv.upper.tolist(), "status": iv.status,
            "held": held.tolist(), "both": bool(held.all()), "ellipse": bool(distance <= ellipse),
            "s": float(np.sqrt(iv.s2)), "n": iv.n, "correlation": float(iv.correlation[0, 1]),
            "loss": result.best.loss, "iterations": result.best.iterations,
            "evaluations": result.best.evaluations, "message": result.best.message, "wall_s": wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--noise", type=float, default=0.5, help="m, standard deviation per coordinate")
    ap.add_argument("--confidence", type=float, default=0.9)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=None, help="keep the targets' folders and coverage.json here")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    scene = load_scene(REPO / "examples" / "small_dam.toml")
    frame = scene.time.frames - 1
    print(f"small dam, {scene.domain.cell_size:g} m cells, frame {frame} observed, noise {args.noise:g} m per "
          f"coordinate, {args.targets} targets, {args.threads} thread(s), load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        save_scene(scene, folder / "scene.toml")
        exact = simulate([scene], progress=False)[0]
        start = time.perf_counter()
        rows = []
        for k in range(args.targets):
            rows.append(one_target(folder, k, exact, frame, args.noise, args.confidence))
            r = rows[-1]
            print(f"target {k:2d}: c1 {r['estimate'][0]:.3f} [{r['lower'][0]:.3f}, {r['upper'][0]:.3f}] kPa, "
                  f"phi3 {r['estimate'][1]:.3f} [{r['lower'][1]:.3f}, {r['upper'][1]:.3f}] deg, held {r['held']}, "
                  f"ellipse {r['ellipse']}, s {r['s']:.3f} m, {r['evaluations']} evaluations, {r['wall_s']:.1f} s, "
                  f"load {os.getloadavg()[0]:.2f}", flush=True)
        wall = time.perf_counter() - start
        summary = summarise(rows, args, wall)
        if args.out is not None:
            (folder / "coverage.json").write_text(json.dumps({"summary": summary, "targets": rows}, indent=1))
    print(json.dumps(summary, indent=1))


def summarise(rows: list[dict], args, wall: float) -> dict:
    held = np.array([r["held"] for r in rows])
    estimates = np.array([r["estimate"] for r in rows])
    widths = np.array([np.subtract(r["upper"], r["lower"]) for r in rows])
    se = np.array([r["standard_error"] for r in rows])
    return {
        "targets": len(rows), "noise_m": args.noise, "confidence": args.confidence,
        "held": {"c1": int(held[:, 0].sum()), "phi3": int(held[:, 1].sum()), "both": int(held.all(axis=1).sum()),
                 "ellipse": int(sum(r["ellipse"] for r in rows))},
        "mean_width": {"c1_kPa": float(widths[:, 0].mean()), "phi3_deg": float(widths[:, 1].mean())},
        "mean_standard_error": {"c1_kPa": float(se[:, 0].mean()), "phi3_deg": float(se[:, 1].mean())},
        "scatter_of_estimates": {"c1_kPa": float(estimates[:, 0].std(ddof=1)), "phi3_deg": float(estimates[:, 1].std(ddof=1))},
        "mean_bias": {"c1_kPa": float(estimates[:, 0].mean() - TRUTH[0]), "phi3_deg": float(estimates[:, 1].mean() - TRUTH[1])},
        "mean_s_m": float(np.mean([r["s"] for r in rows])),
        "wall_s": wall, "wall_per_target_s": wall / len(rows),
        "evaluations_per_target": float(np.mean([r["evaluations"] for r in rows])),
    }


if __name__ == "__main__":
    main()
