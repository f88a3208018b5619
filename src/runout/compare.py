"""`runout compare`: the MPM and a learned engine (the GNS or the neural MPM, whichever the
model file holds) on one scene at the model's resolution, measured against each other and
drawn side by side.

Both get the scene filled at the model's point spacing (runout.learned.scenes.at_model_spacing).
The MPM runs through the cache (runout.mpm.cache: a scene run before is read back, with the
wall time of the run that made it); the engine starts from rest (engine.rollout_trajectory),
as `runout rollout SCENE` does, and runs every frame the MPM has (no early stop).

metrics.json (lengths in m, read at the final frame):

    engine                         the learned engine's name (gns, neural-mpm)
    runout_left_m, runout_right_m  {truth, predicted, error_m, ape_percent}: distance from the
                                   mound's axis (centre_m, the middle of the soil at rest) to
                                   the outermost soil point on that side, MPM (truth) and
                                   engine (predicted); error_m = predicted - truth
    runout_farthest_m              the same for the soil point farthest from the axis
    deposit_iou                    intersection over union of the model-grid cells
                                   (cell_size_m) holding soil points, engine against MPM
    position_mse_mean_m2, _final_m2  soil points, over all frames and at the last (m²)
    wall_s                         {mpm, engine, mpm_over_engine, mpm_cached}

Writes OUT/metrics.json, final.png (MPM left, engine right), animation.mp4 or .gif and
predicted/ (the engine's trajectory); the MPM trajectory stays in the cache (mpm_trajectory).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from runout.errors import InputError, RunFailed
from runout.learned.engine import LearnedEngine, engine_label
from runout.learned.load import load_engine
from runout.learned.scenes import at_model_spacing, scene_at_rest
from runout.learned.training_range import range_warnings
from runout.metrics import absolute_percentage_error, at_common_times, deposit_iou, mound_axis, position_mse, side_runouts
from runout.mpm.budget import check_budget
from runout.mpm.cache import MpmCache
from runout.outputs import check_folder, claim
from runout.plots import animation_name, save_side_by_side, save_side_by_side_animation
from runout.scene import Scene, load_scene
from runout.trajectory import Trajectory, save_trajectory

Log = Callable[[str], None]
COMPARE_FILES = ("metrics.json", "final.png", "predicted")


@dataclass
class Comparison:
    metrics: dict  # as written to OUT/metrics.json
    files: list[Path]  # metrics.json, final.png, the animation, predicted/
    label: str  # the engine's name in lines and pictures


def run_compare(
    scene_path: str | Path, model: str | Path, out: str | Path, frames: int | None = None, device: str = "cpu",
    cache: MpmCache | None = None, force: bool = False, progress: bool = True, log: Log = print, warn: Log = print,
    engine: str | None = None,
) -> Comparison:
    """Run the MPM and the learned engine of checkpoint MODEL on SCENE at its point spacing for
    `frames` frames (None: the scene's) and write the comparison to OUT. `log` gets the line
    saying the scene is refilled, `warn` each value outside the model's training ranges;
    engine: the engine asked for (--engine), checked against the file."""
    scene_path, out = Path(scene_path), Path(out)
    folder = check_folder(out, "compare", COMPARE_FILES + (animation_name(),), force=force,
                          inputs={"the scene": scene_path, "--model": model})
    engine = load_engine(model, device, expect=engine)
    scene = at_model_spacing(load_scene(scene_path), engine, str(scene_path), log)
    scene = _with_frames(scene, frames, engine, scene_path)
    start = scene_at_rest(scene)
    if not start.soil.any():
        raise InputError(f"{scene_path}: every region is fixed, so there is no soil whose runout could be compared.")
    for line in range_warnings(engine, start, str(scene_path)):
        warn(line)
    cache = cache or MpmCache()
    cached = cache.has(scene)
    truth = _mpm(scene, cache, device, progress, scene_path, cached)
    t0 = time.perf_counter()
    predicted = engine.rollout_trajectory(start, truth.n_frames, stop_speed=None, progress=progress)
    engine_wall = time.perf_counter() - t0
    predicted.name = f"{scene.name} ({engine_label(engine)})"
    claim(folder)
    metrics = {
        "scene": str(scene_path), "model": str(model), "engine": engine.name, "frames": truth.n_frames,
        "points": truth.n_points, "soil_points": int(truth.soil.sum()),
        "cell_size_m": scene.domain.cell_size, "point_spacing_m": scene.domain.point_spacing,
        **comparison_metrics(truth, predicted, scene.domain.cell_size),
        "wall_s": _wall_times(truth.info.get("wall_time_s"), engine_wall, cached),
        "mpm_trajectory": str(cache.path(scene)),
    }
    files = _write(out, truth, predicted, metrics, engine)
    return Comparison(metrics, files, engine_label(engine))


def _with_frames(scene: Scene, frames: int | None, engine: LearnedEngine, source: Path) -> Scene:
    """The scene with `frames` frames (None: its own), as many as a rollout from rest needs
    to be compared (the engine's check_frames)."""
    scene = scene.with_frames(frames) if frames is not None else scene
    engine.check_frames(scene.time.frames, "--frames" if frames is not None else f"{source}: time.frames")
    return scene


def _mpm(scene: Scene, cache: MpmCache, device: str, progress: bool, source: Path, cached: bool) -> Trajectory:
    """The scene's MPM trajectory, from the cache or run now (checked against the machine
    first; the engine keeps the same frames of the same points, far less than the MPM needs)."""
    if not cached:
        check_budget([scene], device=device, source=str(source))
    truth = cache.load(scene, device, progress)
    bad = truth.first_nonfinite_frame()
    if bad is not None:
        raise RunFailed(f"the MPM run of {source} diverged (positions are not finite from frame {bad}); "
                        "lower time.cfl or check the materials.")
    return truth


def comparison_metrics(truth: Trajectory, predicted: Trajectory, cell: float) -> dict:
    """Fronts about the mound's axis, deposit overlap on cells of `cell` m and position MSE
    of a prediction (a learned engine) against its truth (MPM), read at the final time both
    have (at_common_times: an engine of frame stride K against the MPM's frames 0, K, 2K, ...)."""
    predicted, truth = at_common_times(predicted, truth)
    centre = mound_axis(truth)
    (true_left, true_right), (left, right) = side_runouts(truth, centre), side_runouts(predicted, centre)
    mse = position_mse(predicted, truth)
    return {
        "centre_m": centre,
        "runout_left_m": _runout(true_left, left),
        "runout_right_m": _runout(true_right, right),
        "runout_farthest_m": _runout(max(true_left, true_right), max(left, right)),
        "deposit_iou": deposit_iou(predicted, truth, cell),
        "position_mse_mean_m2": float(mse.mean()),
        "position_mse_final_m2": float(mse[-1]),
    }


def _runout(truth: float, predicted: float) -> dict:
    ape = float(absolute_percentage_error(predicted, truth))
    return {"truth": truth, "predicted": predicted, "error_m": predicted - truth,
            "ape_percent": ape if math.isfinite(ape) else None}


def _wall_times(mpm: float | None, engine: float, cached: bool) -> dict:
    ratio = mpm / engine if mpm is not None and engine > 0 else None
    return {"mpm": mpm, "engine": engine, "mpm_over_engine": ratio, "mpm_cached": cached}


def _write(out: Path, truth: Trajectory, predicted: Trajectory, metrics: dict, engine: LearnedEngine) -> list[Path]:
    save_trajectory(predicted, out / "predicted", engine.material_width)
    truth, predicted = at_common_times(truth, predicted)
    panels = [(truth, "MPM"), (predicted, engine_label(engine))]
    final = save_side_by_side(panels, out / "final.png")
    animation = save_side_by_side_animation(panels, out / "animation")
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return [out / "metrics.json", final, animation, out / "predicted"]
