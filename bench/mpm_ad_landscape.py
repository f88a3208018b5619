"""Is the exact MPM gradient a useful descent direction? The loss of the paper's dam along one
parameter at a time, beside the reverse-mode gradient (--engine mpm-ad) at a few points.

The target is the MPM run of examples/dam.toml (by default refilled at 8 m cells, 400 frames)
at its own strengths, observed at the last frame with the plain MSE of the inverse spec. For
c of the lower downstream shell and phi of the upper downstream shell in turn (the others at
their true values), the loss is evaluated on a fine sweep (one batched MPM call) and the AD
gradient at a few points; the table compares the AD gradient with the slope of the swept
loss between its neighbours, and the figure (--figure) draws the loss with the AD tangents.
Roughness: the share of sweep intervals whose slope has the sign opposite to the slope
towards the truth (0 for a loss that falls monotonically to the truth).

    .venv/bin/python bench/mpm_ad_landscape.py [--cell-size 8] [--frames 400] [--sweep 31]
        [--points 5] [--threads 1] [--figure docs/figures/mpm_ad_landscape.png]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from runout.inverse import load_inverse_spec, load_observation  # noqa: E402
from runout.inverse.mpm_ad import MpmAutodiff  # noqa: E402
from runout.inverse.mpm_fd import MpmFiniteDifference  # noqa: E402
from runout.mpm import simulate  # noqa: E402
from mpm_ad import bench_scene, write_target  # noqa: E402  (bench/mpm_ad.py, beside this script)

REPO = Path(__file__).resolve().parents[1]
# (material, property, lower, upper, unit); the truth is the scene's value
SWEEPS = [("m1_downstream_lower", "c", 10.0, 100.0, "kPa"), ("m3_downstream_upper", "phi", 5.0, 50.0, "degrees")]


def write_spec(folder: Path, material: str, prop: str, lower: float, upper: float, last_frame: int) -> Path:
    start = 0.5 * (lower + upper)
    path = folder / f"spec_{material}_{prop}.toml"
    path.write_text(f'scene = "scene.toml"\n[target]\ntrajectory = "target"\nframes = [{last_frame}]\n'
                    f"[parameters.{material}]\n{prop} = {{ initial = {start}, lower = {lower}, upper = {upper} }}\n")
    return path


def study(folder: Path, scene, sweep, n_sweep: int, n_points: int) -> dict:
    material, prop, lower, upper, unit = sweep
    spec = load_inverse_spec(write_spec(folder, material, prop, lower, upper, scene.time.frames - 1))
    observation = load_observation(spec)
    m = scene.materials[material]
    truth = m.cohesion if prop == "c" else m.friction_angle
    fd = MpmFiniteDifference(spec, observation)
    values = np.linspace(lower, upper, n_sweep)
    t0 = time.perf_counter()
    runs = simulate([spec.scene_at(np.array([v])) for v in values], progress=False, frames=scene.time.frames)
    sweep_s = time.perf_counter() - t0
    losses = np.array([fd._loss(r.positions) for r in runs])
    ad_engine = MpmAutodiff(spec, observation)
    # AD points: midway between sweep nodes, so the swept slope between neighbours is centred on them
    picks = np.linspace(1, n_sweep - 2, n_points).round().astype(int)
    rows = []
    for k in picks:
        x = 0.5 * (values[k] + values[k + 1])
        ev = ad_engine(np.array([x]))
        swept = (losses[k + 1] - losses[k]) / (values[k + 1] - values[k])
        rows.append({"value": x, "loss": ev.loss, "ad": float(ev.gradient[0]), "swept": float(swept),
                     "seconds": ev.forward_s + ev.backward_s})
    slopes = np.diff(losses) / np.diff(values)
    towards = np.sign(0.5 * (values[1:] + values[:-1]) - truth)  # the sign a loss falling to the truth has
    rough = float(np.mean(np.sign(slopes) == -towards))
    return {"name": f"{prop}[{material}]", "unit": unit, "truth": truth, "values": values, "losses": losses,
            "rows": rows, "rough": rough, "sweep_s": sweep_s}


def draw(results: list[dict], path: Path) -> None:
    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4))
    for ax, r in zip(np.atleast_1d(axes), results):
        ax.plot(r["values"], r["losses"], "o-", ms=3, label="loss, MPM sweep")
        span = (r["values"][-1] - r["values"][0]) / 25
        for k, row in enumerate(r["rows"]):
            xs = np.array([row["value"] - span, row["value"] + span])
            ax.plot(xs, row["loss"] + row["ad"] * (xs - row["value"]), "r-", lw=2,
                    label="AD gradient (tangent)" if k == 0 else None)
        ax.axvline(r["truth"], color="k", ls=":", label="truth")
        ax.set_xlabel(f"{r['name']} ({r['unit']})")
        ax.set_ylabel("loss (m²)")
        ax.set_ylim(bottom=0)
        ax.set_title(f"{r['name']}: wrong-sign share of the sweep {r['rough']:.2f}")
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cell-size", type=float, default=8.0)
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--sweep", type=int, default=31)
    ap.add_argument("--points", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--figure", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    scene = bench_scene(REPO / "examples" / "dam.toml", args.frames, args.cell_size)
    print(f"dam at {args.cell_size:g} m cells, {args.frames} frames; load average {os.getloadavg()[0]:.2f}, "
          f"{args.threads} thread(s)")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        write_target(folder, scene)
        results = [study(folder, scene, s, args.sweep, args.points) for s in SWEEPS]
    print("| parameter | at | loss (m²) | AD gradient | swept slope (neighbours) | AD / swept | AD s |")
    print("|---|---|---|---|---|---|---|")
    for r in results:
        for row in r["rows"]:
            ratio = row["ad"] / row["swept"] if row["swept"] else float("nan")
            print(f"| {r['name']} | {row['value']:.2f} {r['unit']} | {row['loss']:.4g} | {row['ad']:.4g} | "
                  f"{row['swept']:.4g} | {ratio:.3f} | {row['seconds']:.1f} |")
    for r in results:
        print(f"{r['name']}: {len(r['values'])} sweep points in {r['sweep_s']:.1f} s; wrong-sign share {r['rough']:.2f}; "
              f"sweep minimum at {r['values'][np.argmin(r['losses'])]:.2f} {r['unit']} (truth {r['truth']:g})")
    if args.figure:
        draw(results, args.figure)
        print(f"wrote {args.figure}")
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
