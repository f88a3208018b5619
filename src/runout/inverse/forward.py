"""A learned engine (the GNS, the neural MPM) as the inverse's forward model: material
features -> positions at the observed frames (runout.learned.engine.forward_model)."""

from __future__ import annotations

import numpy as np

from runout.errors import InputError
from runout.inverse.loss import spec_loss
from runout.inverse.observation import Observation
from runout.inverse.problem import InverseProblem
from runout.inverse.spec import InverseSpec
from runout.learned.engine import LearnedEngine
from runout.mpm.setup import material_table


def domain_bounds(spec: InverseSpec) -> np.ndarray:
    """[[x_lo, x_hi], [y_lo, y_hi]] (m)."""
    return np.array([[0.0, spec.scene.domain.width], [0.0, spec.scene.domain.height]])


def inverse_problem(
    spec: InverseSpec, observation: Observation, engine: LearnedEngine, checkpoint: bool = True, progress: bool = False
) -> InverseProblem:
    """The inverse problem through a learned engine; the engine's own weights are frozen (no
    gradient wasted on them)."""
    if observation.stride != engine.frame_stride:
        raise InputError(f"the observation was read for frame stride {observation.stride} but the model steps "
                         f"{engine.frame_stride} frames at a time; load it with stride={engine.frame_stride}.")
    engine.freeze()
    forward = engine.forward_model(observation.initial, observation.initial_velocity, observation.particle_type,
                                   observation.frame_dt, list(observation.model_frames), observation.model_steps,
                                   domain_bounds(spec), checkpoint, progress)
    return InverseProblem(
        free=spec.free,
        material_names=spec.scene.material_names,
        table=material_table(spec.scene),
        material_id=observation.material_id,
        feature_width=engine.material_width,
        forward=forward,
        data_loss=spec_loss(spec, observation, engine.device),
        device=str(engine.device),
    )
