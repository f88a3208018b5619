"""The GNS as a learned engine (runout.learned.engine): the GraphNetworkSimulator behind the contract every
command is written against. Each member hands over to the GNS's own code (rollout,
rollout_trajectory, start_window, the schema), so the GNS's figures are those it gave before
the contract existed, bit for bit."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from runout.gns.rollout import rollout, rollout_trajectory, start_window
from runout.gns.simulator import GraphNetworkSimulator
from runout.trajectory import Trajectory


class GnsEngine:
    name = "gns"

    def __init__(self, simulator: GraphNetworkSimulator):
        self.simulator = simulator

    @property
    def data_ranges(self) -> dict | None:
        return self.simulator.data_ranges

    @data_ranges.setter
    def data_ranges(self, ranges: dict | None) -> None:
        self.simulator.data_ranges = ranges

    @property
    def device(self) -> torch.device:
        return self.simulator.vel_mean.device

    @property
    def point_spacing(self) -> float:
        return self.simulator.point_spacing

    @property
    def frame_stride(self) -> int:
        return self.simulator.frame_stride

    @property
    def material_width(self) -> int:
        return self.simulator.schema.material_width

    @property
    def particle_types(self) -> int:
        return self.simulator.schema.particle_types

    def start_frames(self, from_rest: bool = True) -> int:
        return self.simulator.schema.start_frames(from_rest)

    def check_frames(self, frames: int, where: str, from_rest: bool = True) -> None:
        self.simulator.schema.check_frames(frames, where, from_rest)

    def rollout_trajectory(self, start: Trajectory, n_frames: int, stop_speed: float | None = 0.05,
                           progress: bool = False, from_rest: bool = True) -> Trajectory:
        return rollout_trajectory(self.simulator, start, n_frames, stop_speed, progress, from_rest)

    def forward_model(self, initial: np.ndarray, initial_velocity: np.ndarray | None, particle_type: np.ndarray,
                      frame_dt: float, frames: list[int], steps: int, bounds: np.ndarray, checkpoint: bool = True,
                      progress: bool = False) -> Callable[[torch.Tensor], torch.Tensor]:
        """A rollout from the scene at frame 0 (its window the initial positions repeated,
        points that move at frame 0 entering it at their velocity: start_window) for `steps`
        steps, each recomputed in the backward pass when `checkpoint`; the frames observed."""
        history = self.simulator.schema.history
        velocity = np.zeros_like(initial) if initial_velocity is None else initial_velocity
        window = torch.from_numpy(start_window(initial, velocity, history, frame_dt * self.frame_stride)).to(self.device)
        ptype = torch.as_tensor(particle_type, device=self.device)
        chosen = torch.tensor(frames, device=self.device)

        def forward(features: torch.Tensor) -> torch.Tensor:
            positions = rollout(self.simulator, window, ptype, features, steps, bounds, checkpoint=checkpoint,
                                progress=progress)
            return positions[history - 1:][chosen]  # the window's copies of frame 0 are one frame 0

        return forward

    def velocity_statistics(self) -> tuple[list[float], list[float]]:
        """Mean and standard deviation per axis of its training velocities, m per step."""
        return list(self.simulator.stats.vel_mean), list(self.simulator.stats.vel_std)

    def freeze(self) -> None:
        self.simulator.requires_grad_(False)
