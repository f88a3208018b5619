"""Accuracy of a GNS checkpoint, measured for its model card (models/README.md).

    .venv/bin/python scripts/evaluate_model.py models/slope.pt --data DATA --out runs/eval_slope

1. Rollouts of every trajectory in DATA/test.npz from their first 6 frames (held out from
   training): position MSE of the soil points over all frames (m^2) and the relative error
   of the runout front at the last frame.
2. A column collapse (examples/column_a1.toml: 150 x 150 m, phi 22.5 deg, c 25 kPa) filled
   at the model's point spacing, run by the MPM and by the GNS from rest for --frames
   frames: normalised runout of each and their difference; column.png shows both.
Writes OUT/metrics.json and OUT/column.png and prints the metrics.
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


def test_split(simulator, data: Path) -> dict:
    from runout.dataset import split_trajectories
    from runout.gns.rollout import rollout_trajectory
    from runout.metrics import compare

    rows = []
    for k, truth in enumerate(split_trajectories(data, "test")):
        predicted = rollout_trajectory(simulator, truth, truth.n_frames, stop_speed=None)
        result = compare(predicted, truth)
        rows.append({"trajectory": k, "points": truth.n_points, "frames": truth.n_frames,
                     "position_mse_mean_m2": result["position_mse_mean_m2"], "runout_error": result["runout_error"]})
    return {"trajectories": rows,
            "mean_position_mse_m2": float(np.mean([r["position_mse_mean_m2"] for r in rows])),
            "mean_abs_runout_error": float(np.mean([abs(r["runout_error"]) for r in rows]))}


def column(simulator, scene_path: Path, frames: int, out: Path) -> dict:
    from runout.gns.rollout import at_model_spacing, rollout_trajectory, scene_at_rest
    from runout.metrics import normalised_extent
    from runout.mpm import simulate
    from runout.scene import load_scene

    scene = at_model_spacing(load_scene(scene_path), simulator)
    scene = replace(scene, time=replace(scene.time, frames=frames))
    t0 = time.perf_counter()
    truth = simulate([scene], device="cpu", progress=False)[0]
    mpm_s = time.perf_counter() - t0
    predicted = rollout_trajectory(simulator, scene_at_rest(scene, simulator.schema.history), frames, stop_speed=None)
    mpm_ln, gns_ln = normalised_extent(truth), normalised_extent(predicted)
    _draw(truth, predicted, out / "column.png")
    return {"scene": scene_path.name, "cell_size_m": scene.domain.cell_size, "points": truth.n_points, "frames": frames,
            "mpm_normalised_runout": mpm_ln, "gns_normalised_runout": gns_ln,
            "relative_error": (gns_ln - mpm_ln) / mpm_ln if mpm_ln else None, "mpm_wall_s": round(mpm_s, 1)}


def _draw(truth, predicted, path: Path) -> None:
    from runout.plots import save_comparison

    save_comparison(truth, predicted, path, (truth.n_frames - 1, predicted.n_frames - 1), ("MPM, last frame", "GNS, last frame"))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("model", type=Path)
    p.add_argument("--data", type=Path, required=True, help="Dataset folder with test.npz and metadata.json.")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--column", type=Path, default=REPO / "examples" / "column_a1.toml")
    p.add_argument("--frames", type=int, default=240, help="Frames of the column runs.")
    args = p.parse_args()
    from runout.gns.checkpoint import load_simulator

    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    simulator = load_simulator(args.model)
    metrics = {"model": str(args.model), "test_split": test_split(simulator, args.data),
               "column": column(simulator, args.column, args.frames, args.out)}
    (args.out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    print(json.dumps(metrics, indent=1))


if __name__ == "__main__":
    main()
