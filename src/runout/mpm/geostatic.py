"""Geostatic initial stress: sigma'_v from the weight of the material above each point.

Overburden is summed along the vertical ray through each point up to the local free
surface (the top of the contiguous column of points it belongs to), not from the global
top (a known mistake of some codes). sigma_xx = sigma_zz = K0 sigma_v with K0 = 1 - sin(phi)
(Jaky) unless a material gives k0; elastic materials use nu / (1 - nu) (the K0 of each point
is made by runout.mpm.setup.MaterialTable). A column that rests on nothing (a block in
flight) starts stress-free. Compression negative, Pa.
"""

from __future__ import annotations

import numpy as np
import torch

from runout.defaults import GRAVITY  # noqa: F401  (m/s^2; the MPM modules import it from here)


def vertical_stress(
    position: np.ndarray, density: np.ndarray, fixed: np.ndarray, spacing: float
) -> np.ndarray:
    """sigma_v >= 0 (Pa) at each point of one scene on the regular seeding lattice.

    Points share a column when their x agree; a column splits into contiguous segments at
    gaps larger than one spacing. A segment carries weight only if it reaches the base or
    contains fixed (ground) points under its soil."""
    col = np.floor(position[:, 0] / spacing).astype(np.int64)  # lattice x = (i + 1/2) spacing
    order = np.lexsort((-position[:, 1], col))  # by column, then from the top down
    y = position[order, 1]
    c = col[order]
    new_col = np.r_[True, c[1:] != c[:-1]]
    gap = np.r_[True, (y[:-1] - y[1:]) > 1.5 * spacing]
    segment = np.cumsum(new_col | gap) - 1
    weight = np.where(fixed[order], 0.0, density[order] * GRAVITY * spacing)  # Pa per point
    total = np.cumsum(weight)
    start = np.flatnonzero(new_col | gap)
    above = total - weight - (total - weight)[start][segment]  # exclusive sum within the segment
    sigma_v = above + 0.5 * weight
    bottom_y = np.full(segment.max() + 1, np.inf)
    np.minimum.at(bottom_y, segment, y)
    has_fixed = np.zeros(segment.max() + 1, dtype=bool)
    np.logical_or.at(has_fixed, segment, fixed[order])
    supported = (bottom_y < spacing) | has_fixed
    sigma_v = np.where(supported[segment], sigma_v, 0.0)
    out = np.empty_like(sigma_v)
    out[order] = sigma_v
    return out


def initial_stress(sigma_v: torch.Tensor, k0: torch.Tensor) -> torch.Tensor:
    """Stress [P, 4] = (sxx, syy, sxy, szz) from sigma_v [P] >= 0 and K0 [P], compression negative."""
    return torch.stack((-k0 * sigma_v, -sigma_v, torch.zeros_like(sigma_v), -k0 * sigma_v), dim=1)
