"""One learned-engine rollout as `runout rollout` makes it: the starting state from a scene
file, a trajectory folder or a dataset split, and the files the run writes (the engine
itself is whichever the model file holds: runout.learned.load.load_engine)."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from runout import checks
from runout.dataset import load_split_trajectory
from runout.errors import InputError
from runout.contract import material_names_for_width
from runout.learned.engine import LearnedEngine
from runout.learned.scenes import at_model_spacing, scene_at_rest
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
    source: Path, split: str, index: int, engine: LearnedEngine, log: Callable[[str], None] | None = None,
) -> RolloutStart:
    """Where a rollout of SOURCE starts. A scene file is filled at the model's point spacing
    (`log` gets the line saying so when its own cells differ); a trajectory's or dataset's
    particle types must lie in the model's type table (a scene's kinematic and soil types
    always do)."""
    if source.is_file():
        scene = at_model_spacing(load_scene(source), engine, str(source), log)
        return RolloutStart(scene_at_rest(scene), None, scene.time.frames, _ignored_cohesion(scene, engine))
    if (source / "trajectory.npz").is_file():
        truth = load_trajectory(source)
        checks.particle_types([truth.particle_type], engine.particle_types, source / "trajectory.npz", "the model")
        return RolloutStart(truth, truth, truth.n_frames)
    if (source / f"{split}.npz").is_file():
        truth = _dataset_trajectory(source, split, index, engine)
        return RolloutStart(truth, truth, truth.n_frames)
    raise InputError(f"{source}: neither a scene file, a trajectory folder (trajectory.npz) nor a dataset folder with {split}.npz.")


def _dataset_trajectory(folder: Path, split: str, index: int, engine: LearnedEngine) -> Trajectory:
    truth = load_split_trajectory(folder, split, index)
    checks.particle_types([truth.particle_type], engine.particle_types, folder / f"{split}.npz", "the model", index)
    if truth.material_width != engine.material_width:
        show = lambda width: "[" + ", ".join(material_names_for_width(width)) + "]"  # noqa: E731
        raise InputError(f"the model does not fit {folder / f'{split}.npz'}: material_features is "
                         f"{show(engine.material_width)} in the model but {show(truth.material_width)} in the data"
                         + (" (fine-tune with --init to widen the material inputs)." if engine.name == "gns" else "."))
    return truth


def _ignored_cohesion(scene: Scene, engine: LearnedEngine) -> list[str]:
    if engine.material_width < 2 and any(m.cohesion > 0 for m in scene.materials.values()):
        return ["this model has no cohesion input; the scene's cohesion is ignored."]
    return []


def write_rollout_outputs(predicted: Trajectory, truth: Trajectory | None, out: Path, feature_width: int, animation: bool,
                          label: str = "GNS") -> dict:
    """OUT/trajectory.npz + metadata.json, snapshots.png, metrics.json, and against a truth
    position_mse.png; an animation when asked. Returns the metrics. label: the engine's name."""
    predicted.name = f"{predicted.name} ({label})"
    save_trajectory(predicted, out, feature_width)
    save_snapshots(predicted, out / "snapshots.png")
    metrics = {
        "engine": label,
        "frames": predicted.n_frames,
        "runout_m": runout_extent(predicted, -1),
        "normalised_runout": normalised_extent(predicted),
        "wall_s": predicted.info["wall_s"],
    }
    if truth is not None:
        metrics.update(compare(predicted, truth))
        predicted, truth = at_common_times(predicted, truth)  # the MPM at the engine's times
        save_error_plot(position_mse(predicted, truth), predicted.frame_dt, out / "position_mse.png", label)
    if animation:
        metrics["animation"] = str(save_rollout_animation(predicted, truth, out / "animation", label=label))
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics
