"""One GNS rollout run as `runout rollout` makes it: the starting state from a scene file, a
trajectory folder or a dataset split, and the files the run writes (the engine itself is
runout.gns.rollout)."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from runout import checks
from runout.dataset import load_split_trajectory
from runout.errors import InputError
from runout.gns.checkpoint import check_schema
from runout.gns.rollout import at_model_spacing, scene_at_rest
from runout.contract import material_names_for_width
from runout.gns.simulator import Simulator
from runout.metrics import at_common_times, compare, normalised_extent, position_mse, runout_extent
from runout.plots import save_error_plot, save_rollout_animation, save_snapshots
from runout.scene import Scene, load_scene
from runout.trajectory import Trajectory, load_trajectory, save_trajectory

ROLLOUT_FILES = ("trajectory.npz", "metadata.json", "snapshots.png", "metrics.json", "position_mse.png")


@dataclass
class RolloutStart:
    initial: Trajectory  # its frame 0 (or first frames, --from-frames) starts the rollout
    truth: Trajectory | None  # the simulation to compare with, when the source is one
    frames: int  # dataset frames to cover unless asked otherwise: the scene's time.frames or the truth's
    warnings: list[str] = field(default_factory=list)


def initial_state(
    source: Path, split: str, index: int, simulator: Simulator, log: Callable[[str], None] | None = None,
) -> RolloutStart:
    """Where a rollout of SOURCE starts. A scene file is filled at the model's point spacing
    (`log` gets the line saying so when its own cells differ); a trajectory's or dataset's
    particle types must lie in the model's type table (a scene's kinematic and soil types
    always do)."""
    if source.is_file():
        scene = at_model_spacing(load_scene(source), simulator, str(source), log)
        return RolloutStart(scene_at_rest(scene), None, scene.time.frames, _ignored_cohesion(scene, simulator))
    if (source / "trajectory.npz").is_file():
        truth = load_trajectory(source)
        checks.particle_types([truth.particle_type], simulator.schema.particle_types, source / "trajectory.npz", "the model")
        return RolloutStart(truth, truth, truth.n_frames)
    if (source / f"{split}.npz").is_file():
        truth = _dataset_trajectory(source, split, index, simulator)
        return RolloutStart(truth, truth, truth.n_frames)
    raise InputError(f"{source}: neither a scene file, a trajectory folder (trajectory.npz) nor a dataset folder with {split}.npz.")


def _dataset_trajectory(folder: Path, split: str, index: int, simulator: Simulator) -> Trajectory:
    truth = load_split_trajectory(folder, split, index)
    checks.particle_types([truth.particle_type], simulator.schema.particle_types, folder / f"{split}.npz", "the model", index)
    data_schema = simulator.schema.with_material_features(material_names_for_width(truth.material_width))
    check_schema(simulator, data_schema, "the model", folder / f"{split}.npz")
    return truth


def _ignored_cohesion(scene: Scene, simulator: Simulator) -> list[str]:
    if simulator.schema.material_width < 2 and any(m.cohesion > 0 for m in scene.materials.values()):
        return ["this model has no cohesion input; the scene's cohesion is ignored."]
    return []


def write_rollout_outputs(predicted: Trajectory, truth: Trajectory | None, out: Path, feature_width: int, animation: bool) -> dict:
    """OUT/trajectory.npz + metadata.json, snapshots.png, metrics.json, and against a truth
    position_mse.png; an animation when asked. Returns the metrics."""
    predicted.name = f"{predicted.name} (GNS)"
    save_trajectory(predicted, out, feature_width)
    save_snapshots(predicted, out / "snapshots.png")
    metrics = {
        "frames": predicted.n_frames,
        "runout_m": runout_extent(predicted, -1),
        "normalised_runout": normalised_extent(predicted),
        "wall_s": predicted.info["wall_s"],
    }
    if truth is not None:
        metrics.update(compare(predicted, truth))
        predicted, truth = at_common_times(predicted, truth)  # the MPM at the GNS's times
        save_error_plot(position_mse(predicted, truth), predicted.frame_dt, out / "position_mse.png")
    if animation:
        metrics["animation"] = str(save_rollout_animation(predicted, truth, out / "animation"))
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
