"""The contract of a learned engine: what every command asks of the GNS, the neural MPM or any
later engine, so that a command is written once against it and `--model FILE` alone picks the
engine (runout.learned.load.load_engine reads it from the checkpoint).

Units: positions in m, velocities in m/s, frames `frame_stride` dataset frames apart (0.0375 s
each); material features are the codec of runout.contract, [tan phi, c / 100 kPa] (a model of
width 1 reads only tan phi). Every rollout starts from rest: the scene at frame 0, points that
move at frame 0 entering at their velocity.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from runout.trajectory import Trajectory

ENGINE_NAMES = ("gns", "neural-mpm")
LABELS = {"gns": "GNS", "neural-mpm": "neural MPM"}


def engine_label(engine) -> str:
    """The engine's name in pictures and printed lines: GNS, neural MPM."""
    return LABELS.get(engine.name, engine.name)


@runtime_checkable
class LearnedEngine(Protocol):
    name: str  # "gns", "neural-mpm": what --engine calls it and what labels and files say
    data_ranges: dict | None  # what it was trained on (runout.learned.training_range)

    @property
    def device(self) -> torch.device: ...

    @property
    def point_spacing(self) -> float:
        """m between the training scenes' points: every command fills a scene at this spacing."""

    @property
    def frame_stride(self) -> int:
        """Dataset frames per engine step; its rollouts hold frames 0, K, 2K, ..."""

    @property
    def material_width(self) -> int:
        """Material features it reads: 1 ([tan phi]) or 2 ([tan phi, c / 100 kPa])."""

    @property
    def particle_types(self) -> int:
        """Size of its particle-type table: a scene's types must be below it."""

    def start_frames(self, from_rest: bool = True) -> int:
        """Dataset frames a rollout starts from (1: frame 0, from rest)."""

    def check_frames(self, frames: int, where: str, from_rest: bool = True) -> None:
        """InputError unless `frames` dataset frames hold the start and the first predicted frame."""

    def rollout_trajectory(self, start: Trajectory, n_frames: int, stop_speed: float | None = 0.05,
                           progress: bool = False, from_rest: bool = True) -> Trajectory:
        """The engine's run of `start`'s frame 0 over n_frames dataset frames (frame 0 included),
        one frame every frame_stride; stop_speed (m/s) ends it once everything has stopped."""

    def forward_model(self, initial: np.ndarray, initial_velocity: np.ndarray | None, particle_type: np.ndarray,
                      frame_dt: float, frames: list[int], steps: int, bounds: np.ndarray, checkpoint: bool = True,
                      progress: bool = False) -> Callable[[torch.Tensor], torch.Tensor]:
        """The inverse's forward model: material features [N, k] -> positions [F, N, 2] (m) at
        the engine frames `frames` (frame f: f x frame_stride dataset frames, frame_dt s each)
        of a rollout of `steps` engine steps from rest (initial [N, 2] m, initial_velocity
        [N, 2] m/s or None), differentiable in the features; `checkpoint` recomputes steps in
        the backward pass to bound memory."""

    def velocity_statistics(self) -> tuple[list[float], list[float]]:
        """Mean and standard deviation per axis of its training velocities, m per engine step."""

    def freeze(self) -> None:
        """Its own weights stop taking gradients (the inverse moves only the materials)."""
