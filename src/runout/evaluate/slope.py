"""Four-layer slope study (paper §5.1.2): runout on each side of the centre line, material
and displacement fields side by side, displacement-error growth and the wall time of the MPM
and of the learned engine (GNS or neural MPM).

Both engines run the scene at the model's point spacing. Runout on a side is the distance
(m) from the mound's axis (x = 500 m, runout.metrics.mound_axis) to the outermost soil
point; its error is |L_predicted - L_MPM| / L_MPM x 100 (%), "predicted" being the engine's.
The displacement error of a point is the distance (m) between its predicted and MPM positions
at a frame.

Writes OUT/slope/: summary.json, fields_materials.png, fields_displacement.png,
displacement_error.png and predicted/ (the engine's trajectory). Summaries written before the
keys named no engine say gns where these say predicted (runout.evaluate.report reads both).
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

from runout.evaluate.context import StudyContext
from runout.evaluate.model_card import model_card
from runout.evaluate.scenes import EXAMPLES, model_scene, scaled
from runout.evaluate.slope_figures import draw_displacement_error, draw_fields
from runout.learned.engine import engine_label
from runout.learned.load import load_engine
from runout.metrics import absolute_percentage_error, at_common_times, displacement_error, mound_axis, side_runouts
from runout.trajectory import Trajectory, save_trajectory

SLOPE_SCENE = "four_layer_slope.toml"
PAPER_FRAMES = (0, 80, 180)  # and the last frame


def snapshot_frames(n_frames: int, stride: int = 1) -> list[int]:
    """The paper's frames 0, 80, 180 that the run has, and its last frame, as indices of a
    run with one frame every `stride` dataset frames (the nearest)."""
    return sorted({round(f / stride) for f in PAPER_FRAMES if round(f / stride) < n_frames} | {n_frames - 1})


def run_slope(model: Path, out: Path, run: StudyContext, examples: Path = EXAMPLES, frames: int | None = None,
              scale: float = 1.0, rerun_mpm: bool = False) -> dict:
    """Run the study; returns the summary written to OUT/slope/summary.json."""
    folder = Path(out) / "slope"
    engine = load_engine(model, run.device)
    scene = scaled(model_scene(examples, SLOPE_SCENE, engine, run.log), scale)
    scene = scene.with_frames(frames) if frames is not None else scene
    if rerun_mpm:
        run.cache.path(scene).joinpath("metadata.json").unlink(missing_ok=True)
    truth = run.cache.load(scene, run.device, run.progress)
    start = time.perf_counter()
    predicted = engine.rollout_trajectory(truth, truth.n_frames, stop_speed=None, progress=run.progress)
    wall = time.perf_counter() - start
    save_trajectory(predicted, folder / "predicted", engine.material_width)
    truth, predicted = at_common_times(truth, predicted)  # the MPM at the engine's times (frame stride)
    summary = summarise(truth, predicted, mound_axis(truth), wall, run.device, model)
    summary["scale"] = scale
    label = engine_label(engine)
    draw_fields(truth, predicted, snapshot_frames(truth.n_frames, engine.frame_stride), folder, label)
    draw_displacement_error(truth, predicted, folder / "displacement_error.png", label)
    (folder / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def summarise(truth: Trajectory, predicted: Trajectory, centre: float, wall: float, device: str, model: Path) -> dict:
    """centre: x (m) of the mound's axis, where the two sides' runouts are measured from;
    wall: the engine's rollout time (s) on `device`."""
    mpm_left, mpm_right = side_runouts(truth, centre)
    left, right = side_runouts(predicted, centre)
    error = displacement_error(predicted, truth)  # [T, S] m
    info = truth.info
    return {
        "study": "slope",
        "model": model_card(model).to_dict(),
        "frames": predicted.n_frames,
        "points": int(truth.soil.sum()),
        "centre_m": centre,
        "runout_left_m": {"mpm": mpm_left, "predicted": left, "ape_percent": float(absolute_percentage_error(left, mpm_left))},
        "runout_right_m": {"mpm": mpm_right, "predicted": right, "ape_percent": float(absolute_percentage_error(right, mpm_right))},
        "median_displacement_error_final_m": float(np.median(error[-1])),
        "max_displacement_error_final_m": float(error[-1].max()),
        "wall_time_s": {
            "mpm": info.get("wall_time_s"), "mpm_batch_size": info.get("batch_size"),
            "mpm_device": info.get("device"), "mpm_host": info.get("host"),
            "predicted": wall, "predicted_device": str(device), "predicted_host": platform.node(),
        },
    }

