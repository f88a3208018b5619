"""The GNS as the inverse's forward model: material features -> positions at the observed frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from runout.errors import InputError
from runout.gns.checkpoint import load_simulator
from runout.gns.rollout import rollout, start_window
from runout.gns.simulator import Simulator
from runout.inverse.loss import spec_loss
from runout.inverse.observation import Observation
from runout.inverse.problem import ForwardModel, InverseProblem
from runout.inverse.spec import InverseSpec
from runout.mpm.setup import material_table


def gns_forward(
    simulator: Simulator, observation: Observation, bounds: np.ndarray, checkpoint: bool = True, progress: bool = False
) -> ForwardModel:
    """A rollout from the scene at frame 0 (its window the initial positions repeated, points that
    move at frame 0 entering it at their velocity: runout.gns.rollout.start_window) for
    observation.model_steps steps, each step recomputed in the backward pass when `checkpoint`;
    returns the frames observed, [F, N, 2] (m), frame f being step f / frame stride. `progress`
    shows a bar over the forward steps."""
    device = simulator.vel_mean.device
    history = simulator.schema.history
    velocity = np.zeros_like(observation.initial) if observation.initial_velocity is None else observation.initial_velocity
    step_dt = observation.frame_dt * simulator.frame_stride  # s per model step
    window = torch.from_numpy(start_window(observation.initial, velocity, history, step_dt)).to(device)
    particle_type = torch.as_tensor(observation.particle_type, device=device)
    frames = torch.tensor(observation.model_frames, device=device)

    def forward(features: torch.Tensor) -> torch.Tensor:
        positions = rollout(
            simulator, window, particle_type, features, observation.model_steps, bounds,
            checkpoint=checkpoint, progress=progress,
        )
        return positions[history - 1:][frames]  # the window's copies of frame 0 are one frame 0

    return forward


def domain_bounds(spec: InverseSpec) -> np.ndarray:
    """[[x_lo, x_hi], [y_lo, y_hi]] (m)."""
    return np.array([[0.0, spec.scene.domain.width], [0.0, spec.scene.domain.height]])


def inverse_problem(
    spec: InverseSpec, observation: Observation, simulator: Simulator, checkpoint: bool = True, progress: bool = False
) -> InverseProblem:
    """The GNS inverse problem; the model's own weights are frozen (no gradient wasted on them)."""
    if observation.stride != simulator.frame_stride:
        raise InputError(f"the observation was read for frame stride {observation.stride} but the model steps "
                         f"{simulator.frame_stride} frames at a time; load it with stride={simulator.frame_stride}.")
    simulator.requires_grad_(False)
    return InverseProblem(
        free=spec.free,
        material_names=spec.scene.material_names,
        table=material_table(spec.scene),
        material_id=observation.material_id,
        feature_width=simulator.schema.material_width,
        forward=gns_forward(simulator, observation, domain_bounds(spec), checkpoint, progress),
        data_loss=spec_loss(spec, observation, simulator.vel_mean.device),
        device=str(simulator.vel_mean.device),
    )


def load_model(path: Path | None, device: str) -> Simulator:
    if path is None:
        raise InputError("the gns engine needs a trained model; pass --model CHECKPOINT.")
    return load_simulator(path, device=device)
