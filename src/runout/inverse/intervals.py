"""Intervals on back-calculated strengths: the Gauss-Newton (Laplace) covariance at the optimum.

The loss is a sum of squared residuals r (m), one per observed value (DataLoss.residuals).
Near the optimum θ̂ (the free parameters, degrees and kPa) the forward model is taken as
linear, r(θ) ≈ r̂ + J (θ − θ̂), and the residuals as independent Gaussian noise of one
variance, estimated from the residuals themselves:

    s² = r̂ᵀ r̂ / (n − p),   Σ = s² (Jᵀ J)⁻¹,   θ̂_k ± t_{(1 + γ)/2, n − p} √Σ_kk   (confidence γ)

which is the textbook interval of (weighted) least squares, exact for a linear model with
such noise. What it does not know: a deposit's residuals are correlated in space (a misfit
moves a whole region), so n overstates the independent observations and the interval can
be too narrow; and it measures the noise, not an engine that is wrong (docs/inverse-format.md,
"Intervals").

Where the observation does not fix a parameter (its column of J is zero, or J is rank
deficient within RESOLVED), that parameter gets no interval and a sentence instead; a
parameter that L-BFGS-B left on a bound gets a one-sided interval from the bound.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.stats

from runout import checks
from runout.errors import InputError
from runout.inverse.spec import FreeParameter

DEFAULT_CONFIDENCE = 0.9
RESOLVED = 1e-4  # smallest singular value of the column-scaled J, relative to the largest, that counts
NULL_SHARE = 0.1  # a parameter whose share of an unresolved direction exceeds this is not determined
AT_BOUND = 1e-6  # of the bounds' width: a value this close to a bound sits on it

INTERIOR, LOWER, UPPER, ALONE, TOGETHER = "interior", "lower bound", "upper bound", "not determined", "not apart"


@dataclass
class Intervals:
    free: tuple[FreeParameter, ...]
    confidence: float  # e.g. 0.9
    estimate: np.ndarray  # [P] degrees / kPa
    standard_error: np.ndarray  # [P]; inf where not determined
    lower: np.ndarray  # [P] the interval's ends (a bound on a one-sided side); nan where not determined
    upper: np.ndarray
    covariance: np.ndarray  # [P, P]; nan in the rows and columns of parameters not determined
    correlation: np.ndarray  # [P, P], of (JᵀJ)⁻¹ (defined also where s² = 0); nan as covariance
    status: list[str]  # per parameter: INTERIOR, LOWER, UPPER, ALONE or TOGETHER
    partners: list[list[str]]  # per parameter: the names it is not determined apart from (TOGETHER)
    s2: float  # m², the residuals' variance per observed value
    n: int  # observed values
    condition: float  # of Jᵀ J with J's columns scaled to unit length (inf if one is zero)
    t_quantile: float  # t_{(1 + γ)/2, n − p} of the two-sided intervals (one-sided ones at a bound: t_{γ, n − p})

    @property
    def degrees_of_freedom(self) -> int:
        return self.n - len(self.free)


def check_confidence(confidence: float) -> None:
    """InputError unless --confidence is a finite fraction in (0, 1)."""
    checks.number(confidence, "--confidence", None, 0.0, 1.0, lo_open=True, hi_open=True,
                  note="the probability that an interval holds the true value")


def gauss_newton(residuals: np.ndarray, jacobian: np.ndarray, free: tuple[FreeParameter, ...],
                 estimate: np.ndarray, confidence: float) -> Intervals:
    """Intervals at `estimate` [P] from the residuals r [n] (m) there and their Jacobian
    J [n, P] (m per degree or kPa)."""
    r, J = np.asarray(residuals, dtype=float), np.asarray(jacobian, dtype=float)
    n, p = J.shape
    if n <= p:
        raise InputError(f"the observation holds {n} values, too few to estimate the noise and {p} parameters "
                         "(it needs more values than free parameters).")
    s2 = float(r @ r) / (n - p)
    status, partners = _identifiability(J, free)
    determined = np.array([s not in (ALONE, TOGETHER) for s in status])
    inverse = np.full((p, p), np.nan)
    Jd = J[:, determined]
    if determined.any():
        inverse[np.ix_(determined, determined)] = np.linalg.inv(Jd.T @ Jd)
    scale = np.sqrt(np.diag(inverse))
    status = [_bound(q, v) if d else s for q, v, d, s in zip(free, estimate, determined, status)]
    se = np.where(determined, np.sqrt(s2) * scale, np.inf)
    lower, upper, t = _ends(free, np.asarray(estimate, dtype=float), se, status, confidence, n - p)
    return Intervals(free, confidence, np.asarray(estimate, dtype=float), se, lower, upper, s2 * inverse,
                     inverse / np.outer(scale, scale), status, partners, s2, n, _condition(J), t)


def _identifiability(J: np.ndarray, free) -> tuple[list[str], list[list[str]]]:
    """ALONE for a parameter the residuals do not change with, TOGETHER (with its partners) for
    the parameters of a direction that J, its columns scaled to unit length, does not resolve."""
    norms = np.linalg.norm(J, axis=0)
    alone = norms <= 1e-12 * max(float(norms.max()), 1e-300)
    status = [ALONE if a else INTERIOR for a in alone]
    partners: list[list[str]] = [[] for _ in free]
    live = np.flatnonzero(~alone)
    if len(live) < 2:
        return status, partners
    _, sv, vt = np.linalg.svd(J[:, live] / norms[live], full_matrices=False)
    for direction in vt[sv < RESOLVED * sv[0]]:
        group = live[np.abs(direction) > NULL_SHARE]
        for k in group:
            status[k] = TOGETHER
            partners[k] = sorted({*partners[k], *(free[j].name for j in group if j != k)})
    return status, partners


def _condition(J: np.ndarray) -> float:
    norms = np.linalg.norm(J, axis=0)
    if np.any(norms == 0):
        return math.inf
    sv = np.linalg.svd(J / norms, compute_uv=False)
    return math.inf if sv[-1] == 0 else float((sv[0] / sv[-1]) ** 2)


def _bound(p: FreeParameter, value: float) -> str:
    tolerance = AT_BOUND * (p.upper - p.lower)
    if value - p.lower <= tolerance:
        return LOWER
    if p.upper - value <= tolerance:
        return UPPER
    return INTERIOR


def _ends(free, estimate, se, status, confidence, dof):
    """The interval's ends: θ̂ ± t se inside; from the bound to θ̂ ± t_γ se (one-sided) on one."""
    two_sided = float(scipy.stats.t.ppf(0.5 * (1.0 + confidence), dof))
    one_sided = float(scipy.stats.t.ppf(confidence, dof))
    lower, upper = np.full(len(free), np.nan), np.full(len(free), np.nan)
    for k, (p, s) in enumerate(zip(free, status)):
        if s == INTERIOR:
            lower[k], upper[k] = estimate[k] - two_sided * se[k], estimate[k] + two_sided * se[k]
        elif s == LOWER:
            lower[k], upper[k] = p.lower, estimate[k] + one_sided * se[k]
        elif s == UPPER:
            lower[k], upper[k] = estimate[k] - one_sided * se[k], p.upper
    return lower, upper, two_sided


def interval_lines(intervals: Intervals) -> list[str]:
    """One line per parameter, `c[m1] = 40.1 ± 1.3 kPa (90 %)`, or what keeps it from one; then
    the correlation matrix."""
    level = f"({100 * intervals.confidence:g} %)"
    lines = [f"intervals at {level[1:-1]} (Gauss-Newton; s = {math.sqrt(intervals.s2):.3g} m per observed value, "
             f"n = {intervals.n}, p = {len(intervals.free)}, condition number {intervals.condition:.3g}):"]
    for k, (p, status) in enumerate(zip(intervals.free, intervals.status)):
        value, half = intervals.estimate[k], intervals.upper[k] - intervals.estimate[k]
        if status == INTERIOR:
            lines.append(f"{p.name} = {_plus_minus(value, half)} {p.unit} {level}")
        elif status in (LOWER, UPPER):
            ends = _plus_minus(intervals.lower[k], intervals.upper[k] - intervals.lower[k], " to ")
            lines.append(f"{p.name} = {value:.4g} {p.unit}, at its {status}: the interval is one-sided, "
                         f"{ends} {p.unit} {level}")
        elif status == ALONE:
            lines.append(f"{p.name} = {value:.4g} {p.unit}: not determined by this observation "
                         "(the deposit does not change with it)")
        else:
            lines.append(f"{p.name} = {value:.4g} {p.unit}: not determined apart from "
                         f"{', '.join(intervals.partners[k])} by this observation (only a combination of them is)")
    return lines + correlation_lines(intervals)


def correlation_lines(intervals: Intervals) -> list[str]:
    names = [p.name for p in intervals.free]
    width = max(map(len, names))
    lines = ["correlation:"]
    for name, row in zip(names, intervals.correlation):
        cells = "".join("      —" if np.isnan(x) else f" {x:+6.3f}" for x in row)
        lines.append(f"  {name:<{width}}{cells}")
    return lines


def _plus_minus(value: float, half: float, joint: str = " ± ") -> str:
    """value and half to the decimal place of half's second significant digit ("40.1 ± 1.3");
    with joint " to ", value and value + half ("10 to 12.3")."""
    if not half > 0:
        return f"{value:.4g}{joint}{value if joint == ' to ' else 0:.4g}"
    digits = max(0, 1 - math.floor(math.log10(half)))
    second = value + half if joint == " to " else half
    return f"{value:.{digits}f}{joint}{second:.{digits}f}"


def to_json(intervals: Intervals, loss: float, jacobian: str, true_values: list[float] | None) -> dict:
    """uncertainty.json: each parameter's estimate, standard error and interval (null where not
    determined), the correlation and covariance, and the statistics they come from; `jacobian`
    says how J was taken."""
    def finite(x):
        return float(x) if np.isfinite(x) else None

    p = len(intervals.free)
    return {
        "method": "Gauss-Newton (Laplace) covariance s² (JᵀJ)⁻¹ at the optimum, Student-t interval "
                  "(docs/inverse-format.md, Intervals)",
        "confidence": intervals.confidence,
        "loss": loss, "n": intervals.n, "p": p, "degrees_of_freedom": intervals.degrees_of_freedom,
        "s2": intervals.s2, "s2_unit": "m^2 per observed value", "t_quantile": intervals.t_quantile,
        "condition_number": finite(intervals.condition),
        "jacobian": jacobian,
        "parameters": [
            {"name": q.name, "unit": q.unit, "estimate": float(intervals.estimate[k]),
             "standard_error": finite(intervals.standard_error[k]),
             "interval": None if np.isnan(intervals.lower[k]) else [float(intervals.lower[k]), float(intervals.upper[k])],
             "status": intervals.status[k], "not_determined_apart_from": intervals.partners[k],
             "bounds": [q.lower, q.upper], "true": None if true_values is None else true_values[k]}
            for k, q in enumerate(intervals.free)
        ],
        "correlation": [[finite(x) for x in row] for row in intervals.correlation],
        "covariance": [[finite(x) for x in row] for row in intervals.covariance],
    }
