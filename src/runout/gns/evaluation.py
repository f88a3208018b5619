"""How well a GNS rollout follows its ground truth: position error and runout.

Runout here is the horizontal extent of the soil (max x - min x of the moving points, m);
the normalised runout is (L_f - L_0) / L_0 with L_0 the initial extent, and the runout
error is (L_f,GNS - L_f,MPM) / L_f,MPM.
"""

from __future__ import annotations

import numpy as np

from runout.trajectory import Trajectory


def position_mse(predicted: Trajectory, truth: Trajectory) -> np.ndarray:
    """[T] mean squared position error of the soil points per frame (m^2), over the frames
    both trajectories have."""
    t = min(predicted.n_frames, truth.n_frames)
    soil = truth.soil
    diff = predicted.positions[:t, soil].astype(np.float64) - truth.positions[:t, soil]
    return (diff**2).sum(axis=-1).mean(axis=-1)


def runout_extent(traj: Trajectory, frame: int) -> float:
    """Horizontal extent of the soil at a frame (m)."""
    x = traj.positions[frame, traj.soil, 0]
    return float(x.max() - x.min()) if x.size else 0.0


def normalised_runout(traj: Trajectory) -> float:
    initial = runout_extent(traj, 0)
    return (runout_extent(traj, -1) - initial) / initial if initial > 0 else 0.0


def compare(predicted: Trajectory, truth: Trajectory) -> dict:
    """Position MSE (final and mean over time), runouts and the relative runout error, both
    read at the last frame the two trajectories share."""
    t = min(predicted.n_frames, truth.n_frames)
    mse = position_mse(predicted, truth)
    runout_gns, runout_mpm = runout_extent(predicted, t - 1), runout_extent(truth, t - 1)
    initial = runout_extent(truth, 0)
    return {
        "frames_compared": int(t),
        "position_mse_final_m2": float(mse[-1]),
        "position_mse_mean_m2": float(mse.mean()),
        "runout_gns_m": runout_gns,
        "runout_mpm_m": runout_mpm,
        "normalised_runout_gns": (runout_gns - initial) / initial if initial > 0 else 0.0,
        "normalised_runout_mpm": (runout_mpm - initial) / initial if initial > 0 else 0.0,
        "runout_error": (runout_gns - runout_mpm) / runout_mpm if runout_mpm > 0 else 0.0,
    }
