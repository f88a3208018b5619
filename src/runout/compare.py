"""`runout compare`: the MPM and the GNS on one scene at the model's resolution, measured
against each other and drawn side by side.

Both engines get the scene filled at the model's point spacing (at_model_spacing). The MPM
runs through the cache (runout.mpm.cache: a scene run before is read back, with the wall
time of the run that made it); the GNS starts from rest, its window the filled points
held (runout.gns.rollout.rollout_trajectory) as `runout rollout SCENE` does, and runs every frame the MPM has (no early stop).

metrics.json (lengths in m, read at the final frame):

    runout_left_m, runout_right_m  {mpm, gns, error_m, ape_percent}: distance from the mound's
                                   axis (centre_m, the middle of the soil at rest) to the
                                   outermost soil point on that side; error_m = GNS - MPM
    runout_farthest_m              the same for the soil point farthest from the axis
    deposit_iou                    intersection over union of the model-grid cells
                                   (cell_size_m) holding soil points, GNS against MPM
    position_mse_mean_m2, _final_m2  soil points, over all frames and at the last (m²)
    wall_s                         {mpm, gns, mpm_over_gns, mpm_cached}

Writes OUT/metrics.json, final.png (MPM left, GNS right), animation.mp4 or .gif and gns/
(the GNS trajectory); the MPM trajectory stays in the cache (mpm_trajectory).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from runout.contract import FeatureSchema
from runout.errors import InputError, RunFailed
from runout.gns.checkpoint import load_simulator
from runout.gns.rollout import at_model_spacing, rollout_trajectory, scene_at_rest
from runout.gns.training_range import range_warnings
from runout.metrics import absolute_percentage_error, at_common_times, deposit_iou, mound_axis, position_mse, side_runouts
from runout.mpm.budget import check_budget
from runout.mpm.cache import MpmCache
from runout.outputs import check_folder, claim
from runout.plots import animation_name, save_side_by_side, save_side_by_side_animation
from runout.scene import Scene, load_scene
from runout.trajectory import Trajectory, save_trajectory

Log = Callable[[str], None]
COMPARE_FILES = ("metrics.json", "final.png", "gns")


@dataclass
class Comparison:
    metrics: dict  # as written to OUT/metrics.json
    files: list[Path]  # metrics.json, final.png, the animation, gns/


def run_compare(
    scene_path: str | Path, model: str | Path, out: str | Path, frames: int | None = None, device: str = "cpu",
    cache: MpmCache | None = None, force: bool = False, progress: bool = True, log: Log = print, warn: Log = print,
) -> Comparison:
    """Run the MPM and the GNS checkpoint MODEL on SCENE at the model's point spacing for
    `frames` frames (None: the scene's) and write the comparison to OUT. `log` gets the line
    saying the scene is refilled, `warn` each value outside the model's training ranges."""
    scene_path, out = Path(scene_path), Path(out)
    folder = check_folder(out, "compare", COMPARE_FILES + (animation_name(),), force=force, inputs={"the scene": scene_path, "--model": model})
    simulator = load_simulator(model, device)
    scene = at_model_spacing(load_scene(scene_path), simulator, str(scene_path), log)
    scene = _with_frames(scene, frames, simulator.schema, scene_path)
    start = scene_at_rest(scene)
    if not start.soil.any():
        raise InputError(f"{scene_path}: every region is fixed, so there is no soil whose runout could be compared.")
    for line in range_warnings(simulator, start, str(scene_path)):
        warn(line)
    cache = cache or MpmCache()
    cached = cache.has(scene)
    truth = _mpm(scene, cache, device, progress, scene_path, cached)
    t0 = time.perf_counter()
    predicted = rollout_trajectory(simulator, start, truth.n_frames, stop_speed=None, progress=progress)
    gns_wall = time.perf_counter() - t0
    predicted.name = f"{scene.name} (GNS)"
    claim(folder)
    metrics = {
        "scene": str(scene_path), "model": str(model), "frames": truth.n_frames,
        "points": truth.n_points, "soil_points": int(truth.soil.sum()),
        "cell_size_m": scene.domain.cell_size, "point_spacing_m": scene.domain.point_spacing,
        **comparison_metrics(truth, predicted, scene.domain.cell_size),
        "wall_s": _wall_times(truth.info.get("wall_time_s"), gns_wall, cached),
        "mpm_trajectory": str(cache.path(scene)),
    }
    files = _write(out, truth, predicted, metrics, simulator.schema.material_width)
    return Comparison(metrics, files)


def _with_frames(scene: Scene, frames: int | None, schema: FeatureSchema, source: Path) -> Scene:
    """The scene with `frames` frames (None: its own), as many as a rollout from rest needs
    to be compared (FeatureSchema.check_frames)."""
    scene = scene.with_frames(frames) if frames is not None else scene
    schema.check_frames(scene.time.frames, "--frames" if frames is not None else f"{source}: time.frames")
    return scene


def _mpm(scene: Scene, cache: MpmCache, device: str, progress: bool, source: Path, cached: bool) -> Trajectory:
    """The scene's MPM trajectory, from the cache or run now (checked against the machine
    first; the GNS keeps the same frames of the same points, far less than the MPM needs)."""
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
    of a prediction (GNS) against its truth (MPM), read at the final time both have
    (at_common_times: a GNS of frame stride K against the MPM's frames 0, K, 2K, ...)."""
    predicted, truth = at_common_times(predicted, truth)
    centre = mound_axis(truth)
    (mpm_left, mpm_right), (gns_left, gns_right) = side_runouts(truth, centre), side_runouts(predicted, centre)
    mse = position_mse(predicted, truth)
    return {
        "centre_m": centre,
        "runout_left_m": _runout(mpm_left, gns_left),
        "runout_right_m": _runout(mpm_right, gns_right),
        "runout_farthest_m": _runout(max(mpm_left, mpm_right), max(gns_left, gns_right)),
        "deposit_iou": deposit_iou(predicted, truth, cell),
        "position_mse_mean_m2": float(mse.mean()),
        "position_mse_final_m2": float(mse[-1]),
    }


def _runout(mpm: float, gns: float) -> dict:
    ape = float(absolute_percentage_error(gns, mpm))
    return {"mpm": mpm, "gns": gns, "error_m": gns - mpm, "ape_percent": ape if math.isfinite(ape) else None}


def _wall_times(mpm: float | None, gns: float, cached: bool) -> dict:
    ratio = mpm / gns if mpm is not None and gns > 0 else None
    return {"mpm": mpm, "gns": gns, "mpm_over_gns": ratio, "mpm_cached": cached}


def _write(out: Path, truth: Trajectory, predicted: Trajectory, metrics: dict, feature_width: int) -> list[Path]:
    save_trajectory(predicted, out / "gns", feature_width)
    truth, predicted = at_common_times(truth, predicted)
    panels = [(truth, "MPM"), (predicted, "GNS")]
    final = save_side_by_side(panels, out / "final.png")
    animation = save_side_by_side_animation(panels, out / "animation")
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return [out / "metrics.json", final, animation, out / "gns"]
