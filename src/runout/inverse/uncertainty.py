"""`invert --uncertainty`: intervals on the back-calculated strengths (runout.inverse.intervals)
and the loss along each parameter through the optimum, written as uncertainty.json and
profile.png.

The intervals need the Jacobian J [n, P] of the loss's residuals (one per observed coordinate
or thickness bin) with respect to the free parameters at the optimum. Reverse-mode AD, which
drives the optimiser, gives one row of J per backward pass, n of them (672 on the small dam);
the Warp kernels have no forward mode. So each column is a central difference of the engine's
own forward run, the run an evaluation makes without its backward pass: 2P runs `step` of the
bounds apart (one-sided at a bound), one batch on mpm-fd. tests/test_invert_uncertainty.py
checks these columns against reverse-mode AD through mpm-ad and a learned engine.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from runout.inverse.figures import draw_profile
from runout.inverse.intervals import Intervals, gauss_newton, to_json
from runout.inverse.loss import DataLoss
from runout.inverse.optimise import central_stencil, spans
from runout.inverse.spec import FreeParameter
from runout.outputs import write_atomic

UNCERTAINTY_JSON = "uncertainty.json"
PROFILE_PNG = "profile.png"
PROFILE_POINTS = 10  # forward runs per parameter along its profile; the optimum is an eleventh point
PROFILE_HALF_WIDTH = 3.0  # standard errors each side of the optimum, clipped to the bounds


class Forward(Protocol):
    """An engine's forward run, as MpmAutodiff, MpmFiniteDifference and InverseProblem give it."""

    data_loss: DataLoss

    def predict(self, values: np.ndarray, progress: bool = False) -> np.ndarray:
        """[K, P] free values (degrees, kPa) -> [K, F, N, 2] positions (m) at the observed frames."""


@dataclass
class Linearisation:
    """The residuals and their Jacobian at the optimum."""

    values: np.ndarray  # [P] degrees / kPa
    residuals: np.ndarray  # [n] m (DataLoss.residuals)
    jacobian: np.ndarray  # [n, P] m per degree or kPa
    observed: np.ndarray  # [n] bool: the residuals that count as observations (DataLoss.observed)
    loss: float  # m²
    divisor: int  # loss = Σ r² / divisor

    def gauss_newton_loss(self, k: int, delta: np.ndarray) -> np.ndarray:
        """The loss (m²) of the linearised model |r + J_k δ|² / divisor, parameter k moved by δ [K]."""
        moved = self.residuals[None] + np.asarray(delta)[:, None] * self.jacobian[None, :, k]
        return (moved**2).sum(axis=1) / self.divisor


@dataclass
class Profile:
    values: np.ndarray  # [K] of one parameter, the others at the optimum (degrees or kPa), increasing
    losses: np.ndarray  # [K] m²


def linearise(forward: Forward, free: tuple[FreeParameter, ...], values: np.ndarray, step: float,
              progress: bool = False) -> Linearisation:
    """Residuals at `values` and their Jacobian by central differences `step` of the bounds wide."""
    stencil, spacing = central_stencil(free, values, step)
    positions = forward.predict(stencil, progress)
    loss = forward.data_loss
    device = loss.target.device
    residuals = np.stack([loss.residuals(torch.as_tensor(x, device=device)).cpu().numpy() for x in positions])
    jacobian = (residuals[2::2] - residuals[1::2]).T / (spacing * spans(free))  # [n, P]
    centre = torch.as_tensor(positions[0], device=device)
    observed = loss.observed(centre).cpu().numpy() | np.any(jacobian != 0, axis=1)
    return Linearisation(np.asarray(values, dtype=float), residuals[0], jacobian, observed, float(loss(centre)),
                         loss.divisor)


def profiles(forward: Forward, intervals: Intervals, lin: Linearisation, step: float,
             progress: bool = False) -> list[Profile]:
    """The loss along each parameter through the optimum, the others held there: PROFILE_POINTS
    forward runs over ± PROFILE_HALF_WIDTH standard errors (at least ± step of the bounds, all
    of them where the parameter is not determined), clipped to the bounds; all in one predict."""
    grids = []
    for k, p in enumerate(intervals.free):
        half = max(PROFILE_HALF_WIDTH * intervals.standard_error[k], step * (p.upper - p.lower))
        centre = lin.values[k]
        lo, hi = (p.lower, p.upper) if not np.isfinite(half) else (max(p.lower, centre - half), min(p.upper, centre + half))
        grids.append(np.linspace(lo, hi, PROFILE_POINTS))
    rows = np.concatenate([np.repeat(lin.values[None], PROFILE_POINTS, axis=0) for _ in grids])
    for k, grid in enumerate(grids):
        rows[k * PROFILE_POINTS:(k + 1) * PROFILE_POINTS, k] = grid
    positions = forward.predict(rows, progress)
    device = forward.data_loss.target.device
    losses = np.array([float(forward.data_loss(torch.as_tensor(x, device=device))) for x in positions])
    out = []
    for k, grid in enumerate(grids):
        values = np.append(grid, lin.values[k])
        order = np.argsort(values, kind="stable")
        out.append(Profile(values[order], np.append(losses[k * PROFILE_POINTS:(k + 1) * PROFILE_POINTS], lin.loss)[order]))
    return out


def estimate_uncertainty(forward: Forward, free: tuple[FreeParameter, ...], values: np.ndarray, confidence: float,
                         step: float, out_dir: Path, true_values: list[float] | None = None,
                         progress: bool = False) -> Intervals:
    """Intervals at the optimum `values` [P]; writes out_dir/uncertainty.json and profile.png."""
    lin = linearise(forward, free, values, step, progress)
    intervals = gauss_newton(lin.residuals[lin.observed], lin.jacobian[lin.observed], free, lin.values, confidence)
    drawn = profiles(forward, intervals, lin, step, progress)
    record = to_json(intervals, lin.loss, step, true_values)
    record["profile"] = [{"name": p.name, "unit": p.unit, "values": d.values.tolist(), "losses": d.losses.tolist()}
                         for p, d in zip(free, drawn)]
    write_atomic(Path(out_dir) / UNCERTAINTY_JSON, json.dumps(record, indent=1))
    draw_profile(drawn, intervals, lin.gauss_newton_loss, lin.loss, true_values, Path(out_dir) / PROFILE_PNG)
    return intervals
