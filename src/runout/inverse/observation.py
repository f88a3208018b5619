"""The observation an inverse analysis fits: target positions at chosen frames, point by point.

The target's points must be the scene's points in the order `fill_points` seeds them (as a
trajectory from `runout mpm` of the same scene has them). Frames are the target's (dataset)
frames, frame 0 being the scene at rest; a GNS of frame stride K predicts only frames K, 2K,
... (its rollout starts from rest at frame 0 and its step j reaches frame jK), so with it
every observed frame must be one of those and "final" means the last of those the target has.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from runout.defaults import FRAME_DT, PARTICLE_TYPE_KINEMATIC
from runout.errors import InputError
from runout.inverse.spec import InverseSpec, LossSpec
from runout.npz import read_npy
from runout.scene import fill_points
from runout.trajectory import Trajectory, load_trajectory


@dataclass
class Observation:
    frames: tuple[int, ...]  # observed frame numbers (0 is the scene at rest; positive multiples of stride)
    positions: np.ndarray  # [F, N, 2] m, target positions at those frames
    steps: int  # the rollout reaches frame `steps` (dataset frames from the scene at rest)
    initial: np.ndarray  # [N, 2] m, the scene at rest
    particle_type: np.ndarray  # [N]
    material_id: np.ndarray  # [N] index into spec.scene.material_names
    true_values: list[float] | None  # free parameters that made the target, when known
    stride: int = 1  # dataset frames per step of the model rolled out (a GNS's frame stride)
    initial_velocity: np.ndarray | None = None  # [N, 2] m/s at frame 0 (the scene's region velocities); None: at rest
    frame_dt: float = FRAME_DT  # s between the dataset frames that `frames` count

    @property
    def model_steps(self) -> int:
        """Steps of that model from the scene at rest to (at least) frame `steps`; `steps`
        itself at stride 1."""
        return -(-self.steps // self.stride)

    @property
    def model_frames(self) -> tuple[int, ...]:
        """The observed frames as indices of that model's rollout from rest, frame 0 first (frame / stride)."""
        return tuple(f // self.stride for f in self.frames)

    @property
    def moving(self) -> np.ndarray:
        """[N] bool: the points that move (not kinematic)."""
        return self.particle_type != PARTICLE_TYPE_KINEMATIC

    def weights(self, loss: LossSpec) -> np.ndarray:
        """[N] loss weight per point: 0 on kinematic points, else 1 (uniform) or
        1 + front_weight * displacement / largest displacement (toward the runout front)."""
        moving = self.moving.astype(float)
        if loss.weighting == "uniform":
            return moving
        moved = np.linalg.norm(self.positions[-1] - self.initial, axis=1) * moving  # m
        return moving * (1.0 + loss.front_weight * moved / max(float(moved.max()), 1e-12))


def load_observation(spec: InverseSpec, scene_name: str = "the scene", stride: int = 1) -> Observation:
    """The target at its observed frames, checked against the points of spec.scene (called
    `scene_name` in errors, e.g. "the scene at the model's 5 m point spacing (10 m cells)")
    and against the frames a model of frame stride `stride` predicts."""
    points = fill_points(spec.scene)
    if spec.target.trajectory is not None:
        traj = load_trajectory(spec.target.trajectory)
        _check_same_points(traj, points.position, spec.target.trajectory, scene_name)
        frames, steps = _frames_in_trajectory(spec, traj.n_frames, stride)
        positions = traj.positions[list(frames)]
        true_values = _true_values(spec, traj)
    else:
        positions, frames, steps = _observed_positions(spec, len(points), scene_name)
        true_values = None
    _check_stride(spec, frames, stride)
    return Observation(
        frames=frames,
        positions=np.asarray(positions, dtype=np.float64),
        steps=steps,
        initial=points.position,
        particle_type=points.particle_type,
        material_id=points.material_id,
        true_values=true_values,
        stride=stride,
        frame_dt=spec.scene.time.frame_dt,
        initial_velocity=np.where((points.particle_type == PARTICLE_TYPE_KINEMATIC)[:, None], 0.0, points.velocity),
    )


def _check_same_points(traj: Trajectory, initial: np.ndarray, path: Path, scene_name: str) -> None:
    if traj.n_points != len(initial):
        raise InputError(
            f"{path}: the target has {traj.n_points} points but {scene_name} fills {len(initial)}; "
            "the target must be a run of the same scene."
        )
    offset = float(np.abs(traj.positions[0] - initial).max())  # m
    if offset > 0.5:
        raise InputError(
            f"{path}: the target's first frame is up to {offset:.3g} m away from the points of {scene_name}; "
            "the target must be a run of the same scene."
        )


def _frames_in_trajectory(spec: InverseSpec, n_frames: int, stride: int) -> tuple[tuple[int, ...], int]:
    last_target = n_frames - 1
    if last_target < stride:
        raise InputError(f"{spec.target.trajectory}: the target has only {n_frames} frames; "
                         f"it needs more than {stride}.")
    frames = spec.target.frames
    if frames is None:
        last = last_target if spec.steps is None else spec.steps
        frames = (last // stride * stride,)  # the last frame the model predicts
    if frames[-1] > last_target:
        raise InputError(
            f"{spec.source}: observed frame {frames[-1]} is beyond the target trajectory's last frame {last_target}."
        )
    return frames, _steps(spec, frames)


def _check_stride(spec: InverseSpec, frames: tuple[int, ...], stride: int) -> None:
    """Each observed frame must be one that a model of frame stride `stride` predicts."""
    for f in frames:
        if f % stride or f < stride:
            raise InputError(f"{spec.source}: observed frame {f} is not one the model predicts (at frame stride "
                             f"{stride}: the multiples of {stride} from frame {stride}).")


def _steps(spec: InverseSpec, frames: tuple[int, ...]) -> int:
    """Roll out as far as the last observed frame, unless the spec sets the steps."""
    if spec.steps is None:
        return frames[-1]
    last = spec.steps
    if frames[-1] > last:
        raise InputError(
            f"{spec.source}: observed frame {frames[-1]} is beyond the rollout, whose last frame is {last} "
            f"(rollout.steps = {spec.steps})."
        )
    return spec.steps


def _observed_positions(spec: InverseSpec, n_points: int, scene_name: str):
    path = spec.target.positions
    positions = read_npy(path, "observed-positions file")
    if positions.ndim == 2:
        positions = positions[None]
    frames = spec.target.frames
    if frames is None:
        steps = spec.steps if spec.steps is not None else spec.scene.time.frames - 1
        if steps < 1:
            raise InputError(f"{spec.source}: the scene's {spec.scene.time.frames} frames leave no step to roll out.")
        frames = (steps,)
    if positions.shape != (len(frames), n_points, 2):
        raise InputError(
            f"{path}: holds an array of shape {positions.shape}; expected ({len(frames)}, {n_points}, 2) "
            f"for the observed frames and the points of {scene_name}."
        )
    if not np.isfinite(positions).all():
        raise InputError(f"{path}: the observed positions contain NaN or infinite values.")
    return positions, frames, _steps(spec, frames)


def _true_values(spec: InverseSpec, traj: Trajectory) -> list[float] | None:
    """The free parameters' values in the target's material table, when it names the materials."""
    table = {m.name: m for m in traj.materials}
    if not all(p.material in table for p in spec.free):
        return None
    return [float(getattr(table[p.material], p.field)) for p in spec.free]
