"""A scene as a learned engine starts it: filled at the engine's point spacing, and at rest.

Every learned-engine command fills its scene through at_model_spacing, so the engine sees
points spaced like its training data's, and starts it from scene_at_rest: frame 0, with the
scene's region velocities for points thrown at the start.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from runout.errors import InputError
from runout.scene import Scene, fill_points
from runout.trajectory import Trajectory, trajectory_for_scene


def scene_at_rest(scene: Scene, frames: int = 1) -> Trajectory:
    """`frames` identical frames of the scene's filled points: the scene at frame 0, where
    every rollout starts, with its regions' velocities (initial_velocity, m/s; zero for
    kinematic points)."""
    points = fill_points(scene)
    positions = np.repeat(points.position[None].astype(np.float32), frames, axis=0)
    traj = trajectory_for_scene(scene, positions, points.particle_type, points.material_id)
    velocity = np.asarray(points.velocity, dtype=np.float64).copy()
    velocity[~traj.soil] = 0.0
    traj.initial_velocity = velocity
    return traj


def at_model_spacing(scene: Scene, engine, source: str = "<scene>", log: Callable[[str], None] | None = None) -> Scene:
    """The scene with cells sized so that its points sit at the engine's training spacing
    (engine.point_spacing, m). When the scene's own cells differ, one line to `log` says so."""
    spacing = engine.point_spacing  # m
    try:
        filled = scene.with_point_spacing(spacing, source)
    except InputError as exc:
        raise InputError(f"{str(exc).rstrip('.')} (when filled at the model's {spacing:g} m point spacing).") from None
    if log is not None and not math.isclose(filled.domain.cell_size, scene.domain.cell_size, rel_tol=1e-6):
        log(f"filling {source} at the model's {spacing:g} m spacing ({filled.domain.cell_size:g} m cells) "
            f"instead of the scene's {scene.domain.cell_size:g} m cells")
    return filled
