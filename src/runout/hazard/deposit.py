"""What a hazard study reads from one realisation's final frame: the deposit's thickness
along the ground and its two fronts.

Thickness t(x) (m) in bin j (bins of width w m from x = 0): the summed area of the soil
points whose final x falls in the bin, each holding the area it was seeded with (point
spacing², m²: the plane-strain MPM keeps a point's mass, and the deposit's bulking is
ignored), divided by w. It is the height of soil above the ground were the bin's soil spread
level: the area-conserving (Σ t w = soil area) profile that a survey of a deposit gives.
Fixed ground points are not soil and count nowhere.

Fronts (m): "left" and "right" are the distances the leftmost and the rightmost soil point
travelled outward, x_min(0) - x_min(end) and x_max(end) - x_max(0).
"""

from __future__ import annotations

import numpy as np

from runout.trajectory import Trajectory

FRONTS = ("left", "right")


def bin_count(width: float, bin_width: float) -> int:
    """Bins of bin_width (m) that cover a domain width (m)."""
    return int(np.ceil(width / bin_width - 1e-9))


def thickness_profile(traj: Trajectory, spacing: float, bin_width: float, bins: int) -> np.ndarray:
    """[bins] deposit thickness (m) of the final frame (see the module's definition)."""
    x = traj.positions[-1, traj.soil, 0].astype(np.float64)
    index = np.clip(np.floor(x / bin_width).astype(np.int64), 0, bins - 1)
    return np.bincount(index, minlength=bins) * (spacing * spacing / bin_width)


def front_runouts(traj: Trajectory) -> np.ndarray:
    """[2] outward travel (m) of the left and the right front, first to last frame."""
    start, end = traj.positions[0, traj.soil, 0], traj.positions[-1, traj.soil, 0]
    return np.array([start.min() - end.min(), end.max() - start.max()], dtype=np.float64)
