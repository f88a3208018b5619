"""`invert --uncertainty`: intervals on the back-calculated strengths (runout.inverse.intervals)
and the loss along each parameter through the optimum, written as uncertainty.json and
profile.png.

The intervals need the Jacobian J [n, P] of the loss's residuals (one per observed coordinate
or thickness bin) with respect to the free parameters at the optimum, column by column: how
the predicted positions move with each parameter, carried through the loss's residuals by
forward-mode AD. Reverse-mode AD, which drives the optimiser, would give J a row at a time,
n backward passes (672 on the small dam). A learned engine's rollout is plain torch, so its
columns come by forward-mode AD (P passes, each about one rollout), exact like its gradient.
The MPM's Warp kernels have only reverse adjoints, so on mpm-ad and mpm-fd each column is a
central difference of the MPM run itself: 2P runs `step` of the bounds apart (one-sided at a
bound), one batch on mpm-fd. tests/test_invert_uncertainty.py checks both against reverse-mode AD.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
import torch.autograd.forward_ad as fwAD
from tqdm.auto import tqdm

from runout.inverse.figures import draw_profile
from runout.inverse.intervals import Intervals, gauss_newton, to_json
from runout.inverse.loss import DataLoss
from runout.inverse.optimise import central_stencil, spans
from runout.inverse.problem import InverseProblem
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
    how: str  # how the Jacobian was taken

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
    """Residuals at `values` and their Jacobian (module docstring)."""
    centre, tangents, how = position_tangents(forward, free, values, step, progress)
    loss = forward.data_loss
    columns = []
    with fwAD.dual_level():
        for tangent in tangents:  # the residuals are linear (positions) or piecewise linear (thickness) in them
            columns.append(fwAD.unpack_dual(loss.residuals(fwAD.make_dual(centre, tangent))).tangent)
    with torch.no_grad():
        residuals = loss.residuals(centre).cpu().numpy()
        jacobian = torch.stack(columns, dim=1).cpu().numpy()  # [n, P] m per degree or kPa
        observed = loss.observed(centre).cpu().numpy() | np.any(jacobian != 0, axis=1)
        value = float(loss(centre))
    return Linearisation(np.asarray(values, dtype=float), residuals, jacobian, observed, value, loss.divisor, how)


def position_tangents(forward: Forward, free: tuple[FreeParameter, ...], values: np.ndarray, step: float,
                      progress: bool = False) -> tuple[torch.Tensor, torch.Tensor, str]:
    """(positions [F, N, 2] m at `values`, their derivatives [P, F, N, 2] m per degree or kPa, how
    they were taken): forward-mode AD through a learned engine's rollout, else (or should it give
    a value that is not finite) central differences of the forward run."""
    device = forward.data_loss.target.device
    if isinstance(forward, InverseProblem):
        centre, tangents = _forward_mode(forward, values, progress)
        if torch.isfinite(tangents).all():
            return centre, tangents, "forward-mode AD through the rollout"
    stencil, spacing = central_stencil(free, values, step)
    positions = torch.as_tensor(forward.predict(stencil, progress), device=device)
    widths = torch.as_tensor(spacing * spans(free), device=device)
    tangents = (positions[2::2] - positions[1::2]) / widths[:, None, None, None]
    return positions[0], tangents, f"central differences of the forward run, {step:g} of the bounds (one-sided at a bound)"


def _forward_mode(problem: InverseProblem, values: np.ndarray, progress: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The rollout's positions and their derivative along each free parameter, one pass each."""
    centre, tangents = None, []
    with torch.no_grad(), fwAD.dual_level():  # no_grad stops reverse-mode taping only
        for k in tqdm(range(len(values)), desc="rollouts", unit="rollout", disable=not progress):
            v = torch.tensor(np.asarray(values, dtype=np.float64), device=problem.device)
            direction = torch.zeros_like(v)
            direction[k] = 1.0
            primal, tangent = fwAD.unpack_dual(problem.loss(fwAD.make_dual(v, direction))[1].to(torch.float64))
            centre = primal
            tangents.append(torch.zeros_like(primal) if tangent is None else tangent)
    return centre, torch.stack(tangents)


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
    losses = data_losses(forward, rows, progress)
    out = []
    for k, grid in enumerate(grids):
        values = np.append(grid, lin.values[k])
        order = np.argsort(values, kind="stable")
        out.append(Profile(values[order], np.append(losses[k * PROFILE_POINTS:(k + 1) * PROFILE_POINTS], lin.loss)[order]))
    return out


def data_losses(forward: Forward, values: np.ndarray, progress: bool = False) -> np.ndarray:
    """[K] data loss (m²) at each row of values [K, P] (degrees, kPa): the engine's forward runs
    and the inverse's own loss, no gradient."""
    device = forward.data_loss.target.device
    return np.array([float(forward.data_loss(torch.as_tensor(x, device=device)))
                     for x in forward.predict(np.asarray(values, dtype=np.float64), progress)])


def estimate_uncertainty(forward: Forward, free: tuple[FreeParameter, ...], values: np.ndarray, confidence: float,
                         step: float, out_dir: Path, true_values: list[float] | None = None,
                         progress: bool = False, answer_of: str = ".") -> Intervals:
    """Intervals at the optimum `values` [P]; writes out_dir/uncertainty.json and profile.png.
    answer_of: the folder (relative to out_dir) of the run whose answer `values` is."""
    lin = linearise(forward, free, values, step, progress)
    intervals = gauss_newton(lin.residuals[lin.observed], lin.jacobian[lin.observed], free, lin.values, confidence)
    drawn = profiles(forward, intervals, lin, step, progress)
    record = {"answer_of": answer_of, **to_json(intervals, lin.loss, lin.how, true_values)}
    record["profile"] = [{"name": p.name, "unit": p.unit, "values": d.values.tolist(), "losses": d.losses.tolist()}
                         for p, d in zip(free, drawn)]
    write_atomic(Path(out_dir) / UNCERTAINTY_JSON, json.dumps(record, indent=1))
    draw_profile(drawn, intervals, lin.gauss_newton_loss, lin.loss, true_values, Path(out_dir) / PROFILE_PNG)
    return intervals
