"""The material codec of runout.contract as a differentiable function of tensors: the inverse's
way from phi and c to the material features of any learned engine."""

from __future__ import annotations

import torch

from runout.contract import COHESION_SCALE


def encode_materials(friction_angle: torch.Tensor, cohesion: torch.Tensor) -> torch.Tensor:
    """[..., 2] features [tan phi, c / 100 kPa] from phi (degrees) and c (kPa); differentiable."""
    return torch.stack([torch.tan(torch.deg2rad(friction_angle)), cohesion / COHESION_SCALE], dim=-1)
