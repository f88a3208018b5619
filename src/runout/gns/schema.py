"""The GNS contract as the GNS reads it: runout.contract's names (FeatureSchema, HISTORY,
SCHEMA_LIMITS, material_names_for_width) and its material codec as a differentiable function
of tensors, the inverse's way from phi and c to the features.

runout.contract owns them all and is torch-free, so that scenes and files read the contract
without the network; this module adds only the tensor encoder."""

from __future__ import annotations

import torch

from runout.contract import COHESION_SCALE, HISTORY, SCHEMA_LIMITS, FeatureSchema, material_names_for_width

__all__ = ["FeatureSchema", "HISTORY", "SCHEMA_LIMITS", "encode_materials_torch", "material_names_for_width"]


def encode_materials_torch(friction_angle: torch.Tensor, cohesion: torch.Tensor) -> torch.Tensor:
    """[..., 2] features [tan phi, c / 100 kPa] from phi (degrees) and c (kPa); differentiable."""
    return torch.stack([torch.tan(torch.deg2rad(friction_angle)), cohesion / COHESION_SCALE], dim=-1)
