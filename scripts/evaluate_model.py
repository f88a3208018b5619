"""Accuracy of a learned engine's checkpoint (GNS or neural MPM: the file says which),
measured for its model card (models/README.md).

    .venv/bin/python scripts/evaluate_model.py models/slope.pt --data DATA --out runs/eval_slope

1. Rollouts from rest (frame 0 held, as users' scenes start) of the first --limit scenes of
   DATA/test.npz (held out from training; --split valid for the scenes the pilots are judged on), scored against the MPM beside standing still:
   mean position error (m), front errors relative to the fronts' travel, extent runout
   error, mean displacement (runout.evaluate.heldout). With --mirrored, the same scenes
   reflected left-right as well (a model that learned the physics, not the side the training
   slopes face, scores them alike).
2. A column collapse (examples/column_a1.toml: 150 x 150 m, phi 22.5 deg, c 25 kPa) filled
   at the model's point spacing, run by the MPM and by the engine from rest for --frames
   frames: normalised runout of each and their difference; column.png shows both.
3. With --log, the training and validation curves of the run (OUT/curves.png).
Writes OUT/metrics.json (and the pictures) and prints the metrics.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]


def heldout(engine, data: Path, split: str = "test", limit: int | None = None, mirrored: bool = False) -> dict:
    """The first `limit` scenes of the split rolled out from rest, scored beside standing
    still (runout.evaluate.heldout); mirrored: the scenes reflected left-right."""
    from runout.evaluate.heldout import evaluate_heldout

    return evaluate_heldout(engine, data, split, limit, mirrored=mirrored)


def curves(log: Path, path: Path) -> dict:
    """Training loss (mean of each logged group of steps) and validation rollout figures
    against the step, from a run's log.jsonl."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [json.loads(line) for line in log.read_text().splitlines() if line]
    loss = [(r["step"], r["loss"]) for r in rows if "loss" in r]
    valid = [(r["step"], r["valid_runout_error"], r["valid_position_mse_m2"]) for r in rows if "valid_runout_error" in r]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), constrained_layout=True)
    steps, values = zip(*loss)
    axes[0].semilogy(steps, values, lw=0.5, color="0.6", label="mean of each logged group")
    width = max(1, len(values) // 50)
    smooth = np.convolve(values, np.ones(width) / width, mode="valid")
    axes[0].semilogy(steps[width - 1:], smooth, color="C0", label=f"running mean of {width}")
    axes[0].set(xlabel="step", ylabel="training loss (normalised acceleration MSE)", title="training")
    axes[0].legend(fontsize=8)
    if valid:
        vs, ve, vm = zip(*valid)
        axes[1].plot(vs, 100 * np.abs(ve), "o-", color="C1", label="|runout error| (%)")
        twin = axes[1].twinx()
        twin.semilogy(vs, vm, "s--", color="C2", label="position MSE (m²)")
        twin.set_ylabel("position MSE over the rollout (m²)")
        axes[1].legend(loc="upper left", fontsize=8)
        twin.legend(loc="upper right", fontsize=8)
    axes[1].set(xlabel="step", ylabel="|runout error| (%)", title="validation rollouts")
    for ax in axes:  # thousands of steps: six-digit tick labels run into each other
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1000:g}k"))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {"last_step": steps[-1], "loss_last_1000_steps": float(np.mean([v for s, v in loss if s > steps[-1] - 1000])),
            "validation": [{"step": s, "runout_error": e, "position_mse_m2": m} for s, e, m in valid]}


def column(engine, scene_path: Path, frames: int, out: Path) -> dict:
    from runout.learned.engine import engine_label
    from runout.learned.scenes import at_model_spacing, scene_at_rest
    from runout.metrics import normalised_extent
    from runout.mpm import simulate
    from runout.scene import load_scene

    scene = at_model_spacing(load_scene(scene_path), engine)
    scene = replace(scene, time=replace(scene.time, frames=frames))
    t0 = time.perf_counter()
    truth = simulate([scene], device="cpu", progress=False)[0]
    mpm_s = time.perf_counter() - t0
    predicted = engine.rollout_trajectory(scene_at_rest(scene), frames, stop_speed=None)
    mpm_ln, engine_ln = normalised_extent(truth), normalised_extent(predicted)
    _draw(truth, predicted, out / "column.png", engine_label(engine))
    return {"scene": scene_path.name, "cell_size_m": scene.domain.cell_size, "points": truth.n_points, "frames": frames,
            "mpm_normalised_runout": mpm_ln, "engine": engine.name, "engine_normalised_runout": engine_ln,
            "relative_error": (engine_ln - mpm_ln) / mpm_ln if mpm_ln else None, "mpm_wall_s": round(mpm_s, 1)}


def _draw(truth, predicted, path: Path, label: str) -> None:
    from runout.plots import save_comparison

    save_comparison(truth, predicted, path, (truth.n_frames - 1, predicted.n_frames - 1), ("MPM, last frame", f"{label}, last frame"))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path)
    p.add_argument("--data", type=Path, required=True, help="Dataset folder with test.npz and metadata.json.")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--column", type=Path, default=REPO / "examples" / "column_a1.toml")
    p.add_argument("--frames", type=int, default=240, help="Frames of the column runs.")
    p.add_argument("--no-column", action="store_true", help="Skip the column (e.g. for a friction-only base model).")
    p.add_argument("--limit", type=int, default=16, help="Roll out the first LIMIT scenes of the split (at least 16 for a verdict).")
    p.add_argument("--split", choices=("test", "valid"), default="test", help="Held-out split: test, or valid (the pilots' 16 scenes).")
    p.add_argument("--log", type=Path, default=None, help="The run's log.jsonl: draw OUT/curves.png from it.")
    p.add_argument("--mirrored", action="store_true", help="Also roll out the same scenes reflected left-right "
                   "(the families' slopes all fail to the right; a model that learned the physics scores both alike).")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    from runout.learned.load import load_engine

    torch.set_num_threads(args.threads)
    args.out.mkdir(parents=True, exist_ok=True)
    engine = load_engine(args.model)
    metrics = {"model": str(args.model)}
    keys = [f"{args.split}_split"] + ([f"{args.split}_split_mirrored"] if args.mirrored else [])
    for key in keys:
        t0 = time.perf_counter()
        metrics[key] = heldout(engine, args.data, args.split, args.limit, mirrored=key.endswith("mirrored"))
        metrics[key]["rollout_wall_s"] = round(time.perf_counter() - t0, 1)
    if not args.no_column:
        metrics["column"] = column(engine, args.column, args.frames, args.out)
    if args.log is not None:
        metrics["curves"] = curves(args.log, args.out / "curves.png")
    (args.out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    print(json.dumps(metrics, indent=1))
    for key in keys:
        model, still = metrics[key]["model"], metrics[key]["standing_still"]
        scenes = f"{args.split} scenes{' mirrored' if key.endswith('mirrored') else ''}"
        print(f"{args.model}: {model['scenes']} {scenes} from rest: position error {model['position_error_m']:.2f} m "
              f"(standing still {still['position_error_m']:.2f}), fronts {100 * model['front_error']:.1f} % of their travel, "
              f"extent runout error {100 * model['runout_error']:.1f} %, mean displacement {model['displacement_m']:.1f} m "
              f"(MPM {model['displacement_mpm_m']:.1f}); {metrics[key]['rollout_wall_s']:.0f} s")
        for kind, scores in metrics[key]["by_kind"].items():
            m, still = scores["model"], scores["standing_still"]
            print(f"  {kind:15s} {m['scenes']:2d} scenes: position error {m['position_error_m']:.2f} m "
                  f"(standing still {still['position_error_m']:.2f}), fronts {100 * m['front_error']:.1f} %, "
                  f"extent {100 * m['runout_error']:.1f} %, mean displacement {m['displacement_m']:.1f} m (MPM {m['displacement_mpm_m']:.1f})")


if __name__ == "__main__":
    main()
