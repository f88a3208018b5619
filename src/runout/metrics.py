"""Runout metrics, one definition each, for every study and command.

Lengths in metres, velocities in m/s, errors in percent where named so. Both engines give a
Trajectory, so none of these care which engine made it. Two runout measures, named apart:

    runout_front(traj)    largest x of the soil (a flow moving right, e.g. a column)
    runout_extent(traj)   horizontal extent of the soil, max x - min x

and one normalisation of either, L^n = (L_f - L_0) / L_0 (normalised_runout);
normalised_extent(traj) is that of the extent from the first to the last frame. A mound's
two fronts are side_runouts about its axis (mound_axis); deposit_iou compares where two
deposits lie, cell by cell.

Two trajectories are compared at the times both have (at_common_times): a GNS of frame
stride K, one frame every K x 0.0375 s, against the MPM's frames 0, K, 2K, ...
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from runout.errors import InputError
from runout.trajectory import Trajectory


def at_common_times(a: Trajectory, b: Trajectory) -> tuple[Trajectory, Trajectory]:
    """(a, b) at the times both have: the one with the shorter frame interval subsampled to
    the other's (Trajectory.every), then both cut to the frames they share. InputError when
    neither interval is a whole multiple of the other."""
    ratio = a.frame_dt / b.frame_dt
    stride = round(max(ratio, 1 / ratio))
    if not math.isclose(max(ratio, 1 / ratio), stride, rel_tol=1e-6):
        raise InputError(f"frames {a.frame_dt:g} s apart cannot be compared with frames {b.frame_dt:g} s apart; "
                         "one interval must be a whole multiple of the other.")
    a, b = (a, b.every(stride)) if ratio > 1 else (a.every(stride), b)
    t = min(a.n_frames, b.n_frames)
    return _first(a, t), _first(b, t)


def _first(traj: Trajectory, frames: int) -> Trajectory:
    return traj if traj.n_frames == frames else replace(traj, positions=traj.positions[:frames], info=dict(traj.info))


def runout_front(traj: Trajectory, frame: int = -1) -> float:
    """Largest x of the soil points at a frame (m): the front of a flow moving right."""
    return float(traj.positions[frame, traj.soil, 0].max())


def runout_extent(traj: Trajectory, frame: int = -1) -> float:
    """Horizontal extent of the soil at a frame (m): max x - min x; 0 without soil."""
    x = traj.positions[frame, traj.soil, 0]
    return float(x.max() - x.min()) if x.size else 0.0


def normalised_runout(initial_length: float, final_length: float) -> float:
    """L^n = (L_f - L_0) / L_0 (paper §5.1.1); for a column against the left wall both are
    front positions (m)."""
    return (final_length - initial_length) / initial_length


def normalised_extent(traj: Trajectory) -> float:
    """normalised_runout of the soil's extent, first to last frame; 0 when it spans nothing."""
    return _growth(runout_extent(traj, 0), runout_extent(traj, -1))


def _growth(initial: float, final: float) -> float:
    return normalised_runout(initial, final) if initial > 0 else 0.0


def side_runouts(traj: Trajectory, centre: float, frame: int = -1) -> tuple[float, float]:
    """Distances (m) from x = centre to the leftmost and the rightmost soil point."""
    x = traj.positions[frame, traj.soil, 0]
    return float(centre - x.min()), float(x.max() - centre)


def mound_axis(traj: Trajectory) -> float:
    """x (m) halfway between the outermost soil points of the first frame (the axis of a
    symmetric mound at rest: 500 m for the paper's four-layer slope)."""
    x = traj.positions[0, traj.soil, 0]
    return float(x.min() + x.max()) / 2


def occupied_cells(traj: Trajectory, cell: float, frame: int = -1) -> np.ndarray:
    """Sorted distinct indices of the grid cells (side `cell` m, from the domain's lower-left
    corner) that hold soil points at a frame, each cell as one integer ix * rows + iy."""
    lo = np.asarray(traj.bounds, dtype=float)[:, 0]
    rows = int(np.ceil((traj.bounds[1][1] - traj.bounds[1][0]) / cell)) + 1
    index = np.floor((traj.positions[frame, traj.soil].astype(np.float64) - lo) / cell).astype(np.int64)
    return np.unique(index[:, 0] * rows + index[:, 1])


def deposit_iou(predicted: Trajectory, truth: Trajectory, cell: float, frame: int = -1) -> float:
    """Intersection over union of the cells (side `cell` m) occupied by soil at a frame of
    the two trajectories (same domain): 1 for the same deposit, 0 for disjoint ones."""
    a, b = occupied_cells(predicted, cell, frame), occupied_cells(truth, cell, frame)
    union = len(np.union1d(a, b))
    return len(np.intersect1d(a, b)) / union if union else 1.0


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


def position_mse(predicted: Trajectory, truth: Trajectory) -> np.ndarray:
    """[T] mean squared position error of the soil points per frame (m^2), at the times both
    trajectories have (at_common_times)."""
    predicted, truth = at_common_times(predicted, truth)
    soil = truth.soil
    diff = predicted.positions[:, soil].astype(np.float64) - truth.positions[:, soil]
    return (diff**2).sum(axis=-1).mean(axis=-1)


def compare(predicted: Trajectory, truth: Trajectory) -> dict:
    """How well a prediction (a learned engine's rollout) follows its truth (the MPM): position
    MSE (final and mean over time), extent runouts, their normalised runouts from the truth's
    initial extent and the relative runout error (L_f,predicted - L_f,MPM) / L_f,MPM, read at
    the last time the two share (at_common_times; frames_compared counts the shared times).
    The keys say "predicted", not the engine (rollout metadata names it); until 2026-12-07
    they said "gns" for either engine."""
    predicted, truth = at_common_times(predicted, truth)
    t = truth.n_frames
    mse = position_mse(predicted, truth)
    runout_predicted, runout_mpm = runout_extent(predicted, t - 1), runout_extent(truth, t - 1)
    initial = runout_extent(truth, 0)
    return {
        "frames_compared": int(t),
        "position_mse_final_m2": float(mse[-1]),
        "position_mse_mean_m2": float(mse.mean()),
        "runout_predicted_m": runout_predicted,
        "runout_mpm_m": runout_mpm,
        "normalised_runout_predicted": _growth(initial, runout_predicted),
        "normalised_runout_mpm": _growth(initial, runout_mpm),
        "runout_error": (runout_predicted - runout_mpm) / runout_mpm if runout_mpm > 0 else 0.0,
    }


def displacement_error(predicted: Trajectory, truth: Trajectory) -> np.ndarray:
    """[T, S] distance (m) between predicted and true positions of the S soil points, at the
    times both trajectories have (at_common_times)."""
    predicted, truth = at_common_times(predicted, truth)
    soil = truth.soil
    return np.linalg.norm(predicted.positions[:, soil].astype(float) - truth.positions[:, soil], axis=-1)


def final_displacement(traj: Trajectory) -> np.ndarray:
    """[S] distance (m) each soil point moved from the first to the last frame."""
    return soil_displacement(traj.positions, traj.soil)


def soil_displacement(positions: np.ndarray, soil: np.ndarray) -> np.ndarray:
    """[S] distance (m) each soil point (soil: [N] mask) of positions [T, N, 2] moved from the
    first to the last frame."""
    return np.linalg.norm(positions[-1, soil].astype(float) - positions[0, soil], axis=-1)


def velocities(traj: Trajectory, frame: int) -> np.ndarray:
    """[N, 2] velocity (m/s) of every point over the frame interval ending at `frame` (>= 1)."""
    step = traj.positions[frame].astype(float) - traj.positions[frame - 1]
    return step / traj.frame_dt


def front_errors(predicted: Trajectory, truth: Trajectory) -> dict:
    """The two fronts of the soil (leftmost and rightmost x) at the last time both
    trajectories share, against the truth's: per side the error (m) and the truth's travel
    from its first frame (m), and the mean |position error| over every soil point and shared
    frame (m). Standing still scores each front's error as its whole travel."""
    predicted, truth = at_common_times(predicted, truth)
    out = {"position_error_mean_m": float(displacement_error(predicted, truth).mean())}
    for side, pick in (("left", np.min), ("right", np.max)):
        p, t, t0 = (float(pick(tr.positions[f, tr.soil, 0])) for tr, f in ((predicted, -1), (truth, -1), (truth, 0)))
        out[f"{side}_front_error_m"] = p - t
        out[f"{side}_front_travel_m"] = abs(t - t0)
    return out
