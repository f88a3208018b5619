"""Runout metrics shared by every study: runout fronts, normalised runout, errors, R².

Lengths in metres, velocities in m/s, errors in percent where named so. Both engines give a
Trajectory, so none of these care which engine made it. The position MSE per frame is the
GNS engineer's (runout.gns.evaluation), re-exported here so studies import one module.
"""

from __future__ import annotations

import numpy as np

from runout.gns.evaluation import position_mse
from runout.trajectory import Trajectory

__all__ = [
    "absolute_percentage_error", "coefficient_of_variation", "displacement_error", "final_displacement",
    "normalised_runout", "position_mse", "r_squared", "runout_front", "side_runouts", "velocities",
]


def runout_front(traj: Trajectory, frame: int = -1) -> float:
    """Largest x of the soil points at a frame (m): the front of a flow moving right."""
    return float(traj.positions[frame, traj.soil, 0].max())


def normalised_runout(initial_length: float, final_length: float) -> float:
    """L^n = (L_f - L_0) / L_0 (paper §5.1.1); for a column against the left wall both are
    front positions (m)."""
    return (final_length - initial_length) / initial_length


def side_runouts(traj: Trajectory, centre: float, frame: int = -1) -> tuple[float, float]:
    """Distances (m) from x = centre to the leftmost and the rightmost soil point."""
    x = traj.positions[frame, traj.soil, 0]
    return float(centre - x.min()), float(x.max() - centre)


def absolute_percentage_error(predicted, truth) -> np.ndarray:
    """|predicted - truth| / |truth| x 100 (%), elementwise; NaN where the truth is 0."""
    predicted, truth = np.asarray(predicted, dtype=float), np.asarray(truth, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(truth != 0, np.abs(predicted - truth) / np.abs(truth) * 100.0, np.nan)


def coefficient_of_variation(values) -> float:
    """Population standard deviation over the mean (dimensionless), NaNs ignored."""
    values = np.asarray(values, dtype=float)
    return float(np.nanstd(values) / np.nanmean(values))


def r_squared(predicted, truth) -> float:
    """Coefficient of determination of predictions against the truth (the 1:1 line, not a
    fitted one): 1 - sum (p - t)^2 / sum (t - mean t)^2."""
    predicted, truth = np.asarray(predicted, dtype=float), np.asarray(truth, dtype=float)
    residual = np.sum((predicted - truth) ** 2)
    spread = np.sum((truth - truth.mean()) ** 2)
    return float(1.0 - residual / spread) if spread > 0 else float("nan")


def displacement_error(predicted: Trajectory, truth: Trajectory) -> np.ndarray:
    """[T, S] distance (m) between predicted and true positions of the S soil points, over
    the frames both trajectories have."""
    t = min(predicted.n_frames, truth.n_frames)
    soil = truth.soil
    return np.linalg.norm(predicted.positions[:t, soil].astype(float) - truth.positions[:t, soil], axis=-1)


def final_displacement(traj: Trajectory) -> np.ndarray:
    """[S] distance (m) each soil point moved from the first to the last frame."""
    soil = traj.soil
    return np.linalg.norm(traj.positions[-1, soil].astype(float) - traj.positions[0, soil], axis=-1)


def velocities(traj: Trajectory, frame: int) -> np.ndarray:
    """[N, 2] velocity (m/s) of every point over the frame interval ending at `frame` (>= 1)."""
    step = traj.positions[frame].astype(float) - traj.positions[frame - 1]
    return step / traj.frame_dt
