"""L-BFGS-B in a normalised parameter space, with history, resume and several starting points.

Each free parameter is mapped to u in [0, 1] between its bounds (value = lower + u (upper -
lower)), so L-BFGS-B sees bounds [0, 1] and gradients of comparable size. An evaluator maps
physical values to an Evaluation (loss and gradient); it is the GNS problem or the MPM
finite-difference engine alike.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import scipy.optimize
from scipy.stats import qmc

from runout.errors import InputError
from runout.inverse.history import History, Record, RunInfo
from runout.inverse.problem import Evaluation
from runout.inverse.spec import FreeParameter, OptimiserSpec
from runout.npz import read_npy

Evaluator = Callable[[np.ndarray], Evaluation]
Log = Callable[[str], None]
DEPOSITS = "deposits"  # folder of [N, 2] predicted positions at the last observed frame, one per evaluation


@dataclass
class StartResult:
    out_dir: Path
    start: np.ndarray  # [P] physical values it started from
    values: np.ndarray  # [P] physical values L-BFGS-B ended at
    loss: float  # m^2 at `values`
    iterations: int
    evaluations: int
    message: str
    history: History


def to_physical(free: tuple[FreeParameter, ...], u: np.ndarray) -> np.ndarray:
    lower = np.array([p.lower for p in free])
    upper = np.array([p.upper for p in free])
    return np.clip(lower + np.asarray(u) * (upper - lower), lower, upper)  # clip: rounding only


def spans(free: tuple[FreeParameter, ...]) -> np.ndarray:
    return np.array([p.upper - p.lower for p in free])


def central_stencil(free: tuple[FreeParameter, ...], values: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """([2P + 1, P] physical values: `values`, then one below and one above per parameter, a
    fraction `step` of its bounds away, shortened one-sidedly at a bound; [P] the distance
    between each pair in the normalised space)."""
    u = np.array([p.normalise(v) for p, v in zip(free, values)])
    points = [u]
    spacing = np.empty(len(u))
    for k in range(len(u)):
        below, above = u.copy(), u.copy()
        below[k] = max(u[k] - step, 0.0)
        above[k] = min(u[k] + step, 1.0)
        points += [below, above]
        spacing[k] = above[k] - below[k]
    return np.array([to_physical(free, x) for x in points]), spacing


def deposit_path(out_dir: Path, evaluation: int) -> Path:
    return Path(out_dir) / DEPOSITS / f"eval_{evaluation:04d}.npy"


def read_deposit(out_dir: Path, evaluation: int, points: int | None = None) -> np.ndarray:
    """The [N, 2] deposit (m) a run recorded for `evaluation`, read without pickle and
    checked: finite, and `points` rows when given."""
    path = deposit_path(out_dir, evaluation)
    deposit = read_npy(path, "deposit file of a recorded evaluation")
    rows = "N" if points is None else points
    if deposit.ndim != 2 or deposit.shape[1] != 2 or (points is not None and deposit.shape[0] != points):
        raise InputError(f"{path}: holds an array of shape {deposit.shape}; expected ({rows}, 2) positions in m.")
    if not np.isfinite(deposit).all():
        raise InputError(f"{path}: the deposit holds NaN or infinite positions where only finite ones are allowed.")
    return deposit


class EvaluationsSpent(Exception):
    """L-BFGS-B asked for one evaluation more than optimiser.max_evaluations allows."""


class RecordedObjective:
    """scipy's fun(u) -> (loss, d loss / d u). Calls that a history already holds are replayed
    from it in order; new ones are evaluated, recorded and written before returning. The
    call after max_evaluations raises EvaluationsSpent (scipy's maxfun is checked only
    between iterations, so a line search could overrun it)."""

    def __init__(self, evaluate: Evaluator, free: tuple[FreeParameter, ...], history: History, log: Log | None,
                 max_evaluations: int | None = None):
        self.evaluate = evaluate
        self.free = free
        self.history = history
        self.log = log
        self.max_evaluations = max_evaluations
        self.calls = 0
        self.iteration = 0

    def __call__(self, u: np.ndarray) -> tuple[float, np.ndarray]:
        k = self.calls
        if self.max_evaluations is not None and k >= self.max_evaluations:
            raise EvaluationsSpent
        self.calls += 1
        if k < len(self.history.records):
            record = self._replay(k, u)
        else:
            record = self._evaluate(k, u)
        if k == 0:
            self.history.mark_iteration(u, 0)
        return record.loss, np.array(record.gradient_normalised)

    def accept(self, intermediate_result) -> None:
        """L-BFGS-B callback: the point it just moved to is its next iterate."""
        self.iteration += 1
        self.history.mark_iteration(intermediate_result.x, self.iteration)

    def _replay(self, k: int, u: np.ndarray) -> Record:
        record = self.history.records[k]
        if not np.array_equal(record.normalised, u):
            raise InputError(
                f"{self.history.out_dir}: evaluation {k} of the recorded history was at another point; "
                "the history does not belong to this run, so remove it or use another --out folder."
            )
        read_deposit(self.history.out_dir, k)
        return record

    def _evaluate(self, k: int, u: np.ndarray) -> Record:
        ev = self.evaluate(to_physical(self.free, u))
        record = Record(
            evaluation=k, iteration=None, normalised=[float(x) for x in u], values=ev.values.tolist(),
            loss=ev.loss, gradient=ev.gradient.tolist(),
            gradient_normalised=(ev.gradient * spans(self.free)).tolist(),
            forward_s=ev.forward_s, backward_s=ev.backward_s, peak_memory_bytes=ev.peak_memory_bytes,
        )
        _save_atomic(deposit_path(self.history.out_dir, k), ev.deposit)
        self.history.add(record)
        if self.log:
            self.log(_describe(record, self.free))
        return record


def _describe(r: Record, free: tuple[FreeParameter, ...]) -> str:
    values = ", ".join(f"{p.name} = {v:.4g} {p.unit}" for p, v in zip(free, r.values))
    return (f"evaluation {r.evaluation}: loss {r.loss:.4g} m^2 at {values} "
            f"(forward {r.forward_s:.2f} s, backward {r.backward_s:.2f} s, {r.peak_memory_bytes / 1e6:.1f} MB held)")


def _save_atomic(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.save(f, array)
    os.replace(tmp, path)


def minimise(
    evaluate: Evaluator,
    free: tuple[FreeParameter, ...],
    start: np.ndarray,  # [P] normalised
    out_dir: Path,
    info: RunInfo,
    options: OptimiserSpec,
    memory_measure: str,
    true_values: list[float] | None = None,
    log: Log | None = None,
) -> StartResult:
    """One L-BFGS-B run from `start`, resuming from out_dir's history when there is one."""
    history = History(out_dir, free, info, memory_measure, true_values)
    history.resume_from_disk()
    if log and history.records:
        log(f"{out_dir}: replaying {len(history.records)} recorded evaluations")
    objective = RecordedObjective(evaluate, free, history, log, options.max_evaluations)
    try:
        result = scipy.optimize.minimize(
            objective, np.asarray(start, dtype=np.float64), method="L-BFGS-B", jac=True,
            bounds=[(0.0, 1.0)] * len(free), callback=objective.accept,
            options={"maxiter": options.max_iterations, "maxfun": options.max_evaluations,
                     "ftol": options.ftol, "gtol": options.gtol},
        )
        x, loss, iterations, evaluations = result.x, float(result.fun), int(result.nit), int(result.nfev)
        message, success = str(result.message), bool(result.success)
    except EvaluationsSpent:
        best = min(history.records, key=lambda r: r.loss)
        x, loss, iterations, evaluations = np.array(best.normalised), best.loss, objective.iteration, objective.calls
        message, success = f"STOP: max_evaluations = {options.max_evaluations} reached (best evaluation kept)", False
    values = to_physical(free, x)
    history.finish({
        "values": values.tolist(), "loss": loss, "iterations": iterations,
        "evaluations": evaluations, "message": message, "success": success,
    })
    return StartResult(Path(out_dir), to_physical(free, start), values, loss, iterations, evaluations, message, history)


def starting_points(free: tuple[FreeParameter, ...], count: int) -> np.ndarray:
    """[count, P] normalised starts: the spec's initial values, then a Latin hypercube (seed 0)."""
    first = np.array([[p.normalise(p.initial) for p in free]])
    if count == 1:
        return first
    others = qmc.LatinHypercube(d=len(free), rng=0).random(count - 1)
    return np.vstack([first, others])


def run_starts(
    evaluate: Evaluator,
    free: tuple[FreeParameter, ...],
    count: int,
    out_dir: Path,
    info: RunInfo,
    options: OptimiserSpec,
    memory_measure: str,
    true_values: list[float] | None = None,
    log: Log | None = None,
) -> list[StartResult]:
    """L-BFGS-B from `count` starting points; one start writes to out_dir, several to out_dir/start_KK."""
    results = []
    for k, start in enumerate(starting_points(free, count)):
        folder = Path(out_dir) if count == 1 else Path(out_dir) / f"start_{k:02d}"
        if log and count > 1:
            log(f"start {k + 1} of {count}")
        run_info = replace(info, start=[float(x) for x in start])
        results.append(minimise(evaluate, free, start, folder, run_info, options, memory_measure, true_values, log))
    return results


def spread(results: list[StartResult], free: tuple[FreeParameter, ...]) -> list[dict]:
    """Per parameter: the range of the answers over the starts, also as a fraction of its bounds."""
    answers = np.array([r.values for r in results])  # [K, P]
    rows = []
    for k, p in enumerate(free):
        col = answers[:, k]
        rows.append({
            "name": p.name, "unit": p.unit, "lower": p.lower, "upper": p.upper,
            "min": float(col.min()), "max": float(col.max()), "mean": float(col.mean()),
            "std": float(col.std()), "range_of_bounds": float((col.max() - col.min()) / (p.upper - p.lower)),
        })
    return rows
