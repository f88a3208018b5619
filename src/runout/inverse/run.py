"""`invert`: the whole inverse analysis, as the command line runs it (also for notebooks)."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from runout.errors import InputError
from runout.inverse.figures import (
    check_iterations, default_iterations, draw_deposits, draw_loss, draw_parameters, draw_starts, pick_iterations,
)
from runout.inverse.history import RunInfo
from runout.inverse.intervals import DEFAULT_CONFIDENCE, Intervals, check_confidence, interval_lines
from runout.inverse.memory import PeakMemory
from runout.inverse.mpm_fd import check_step
from runout.inverse.observation import Observation, load_observation
from runout.inverse.optimise import Log, StartResult, run_starts, spread
from runout.inverse.spec import InverseSpec, load_inverse_spec
from runout.inverse.uncertainty import PROFILE_PNG, PROFILE_POINTS, UNCERTAINTY_JSON, data_losses, estimate_uncertainty
from runout.outputs import check_folder, claim

LEARNED = ("gns", "neural-mpm")  # engines read from --model (runout.learned)
ENGINES = (*LEARNED, "mpm-fd", "mpm-ad")
MAX_STARTS = 100


@dataclass
class InversionResult:
    spec: InverseSpec
    starts: list[StartResult]
    spread: list[dict]  # per parameter, over the starts (see optimise.spread)
    intervals: Intervals | None = None  # at the best start's answer, with uncertainty=True
    loss_at_truth: float | None = None  # m², the data loss at the target's true values; None: not known

    @property
    def best(self) -> StartResult:
        return min(self.starts, key=lambda r: r.loss)


def invert(
    spec_path: str | Path,
    out_dir: str | Path,
    model: str | Path | None = None,
    device: str = "cpu",
    starts: int = 1,
    engine: str | None = None,
    fd_step: float = 0.01,
    checkpoint: bool = True,
    plot_iterations: str | None = None,
    log: Log | None = None,
    progress: bool = False,
    warn: Log | None = None,
    force: bool = False,
    uncertainty: bool = False,
    confidence: float = DEFAULT_CONFIDENCE,
) -> InversionResult:
    """Back-calculate the spec's free parameters; write histories and figures to out_dir.

    engine: mpm-ad or mpm-fd (through the MPM itself), or a learned engine (gns, neural-mpm),
    whose model file names it: with a model and no engine, the file's engine is used. A
    learned engine's scene is filled at its point spacing (a line to `log` when its own cells
    differ), so the target must be a run of the scene at that spacing.
    A run killed part-way resumes when called again with the same arguments (force: start
    afresh). `log` receives one line per evaluation, `warn` each warning (e.g. a value
    outside the model's training range); `progress` shows a bar over each forward run.
    uncertainty: then intervals at `confidence` on the best start's answer (runout.inverse.intervals),
    written with the loss along each parameter to uncertainty.json and profile.png in out_dir;
    a finished run is replayed from its history, not redone.
    When the target names the true values, one more forward run gives the data loss there
    (`loss_at_truth`): above the answer's, the engine's response is off; about equal, the loss is flat."""
    if engine is not None and engine not in ENGINES:
        raise InputError(f"--engine {engine!r} must be one of {', '.join(ENGINES)}.")
    if not 1 <= starts <= MAX_STARTS:
        raise InputError(f"--starts {starts} is outside the allowed range [1, {MAX_STARTS}].")
    check_step(fd_step)
    check_confidence(confidence)
    spec = load_inverse_spec(spec_path)
    chosen = check_iterations(plot_iterations, spec.optimiser.max_iterations)
    inputs = {"the spec": spec_path, "its scene": spec.scene_path, "its target": spec.target.trajectory or spec.target.positions,
              "--model": model}
    folder = check_folder(out_dir, "invert", _writes(starts, uncertainty), mode="resume", force=force, inputs=inputs)
    learned, filled = None, "the scene"
    if engine is None or engine in LEARNED:
        learned = _learned_engine(model, device, engine)
        engine = learned.name
        spec, filled = _at_model_spacing(spec, learned, log)
    observation = load_observation(spec, filled, 1 if learned is None else learned.frame_stride)
    evaluate, forward, model_name = _evaluator(spec, observation, engine, learned, model, device, fd_step, checkpoint,
                                               progress, warn)
    claim(folder)
    info = RunInfo(digest=spec.digest, engine=engine, model=model_name, start=[])
    results = run_starts(
        evaluate, spec.free, starts, Path(out_dir), info, spec.optimiser,
        PeakMemory(device).measure, observation.true_values, log,
    )
    for result in results:
        _draw(result, observation, chosen, warn)
    inversion = InversionResult(spec, results, spread(results, spec.free))
    if observation.true_values is not None:
        inversion.loss_at_truth = float(data_losses(forward, [observation.true_values], progress)[0])
        for result in results:  # each start's history.json keeps it beside its answer
            result.history.finish({**(result.history.result or {}), "data_loss_at_true_m2": inversion.loss_at_truth})
    if starts > 1:
        _write_starts(inversion, Path(out_dir))
    if uncertainty:
        if log:
            log(f"intervals at the answer of {inversion.best.out_dir}: the Jacobian, then {PROFILE_POINTS * len(spec.free)} runs "
                "along the parameters")
        best = inversion.best
        inversion.intervals = estimate_uncertainty(forward, spec.free, best.values, confidence, fd_step, Path(out_dir),
                                                   observation.true_values, progress,
                                                   best.out_dir.relative_to(out_dir).as_posix())
    return inversion


def _writes(starts: int, uncertainty: bool) -> tuple[str, ...]:
    per_start = ("history.json", "history.csv", "loss.png", "parameters.png", "deposit.png", "deposits")
    ends = (UNCERTAINTY_JSON, PROFILE_PNG) if uncertainty else ()
    if starts == 1:
        return per_start + ends
    return tuple(f"start_{k:02d}" for k in range(starts)) + ("starts.json", "starts.csv", "starts.png") + ends


def _learned_engine(model, device: str, engine: str | None):
    from runout.learned.load import load_engine

    if model is None and engine is None:
        raise InputError("give --model CHECKPOINT (a learned engine's file) or --engine mpm-ad or mpm-fd.")
    if model is None:
        raise InputError(f"the {engine} engine needs a trained model; pass --model CHECKPOINT.")
    return load_engine(Path(model), device, expect=engine)


def _at_model_spacing(spec: InverseSpec, engine, log: Log | None) -> tuple[InverseSpec, str]:
    """The spec with its scene filled at the engine's point spacing, and the words for that
    scene in errors about the target (which must be a run of it)."""
    from runout.learned.scenes import at_model_spacing

    scene = at_model_spacing(spec.scene, engine, f"the scene of {spec.source}", log)
    cell = scene.domain.cell_size
    same = cell == spec.scene.domain.cell_size
    filled = "the scene" if same else f"the scene at the model's {engine.point_spacing:g} m point spacing ({cell:g} m cells)"
    return replace(spec, scene=scene), filled


def _evaluator(spec, observation, engine, learned, model, device, fd_step, checkpoint, progress, warn):
    """(evaluate: values -> Evaluation, the forward run that predicts positions, the model's path or "")."""
    if engine == "mpm-fd":
        from runout.inverse.mpm_fd import MpmFiniteDifference
        from runout.mpm.budget import check_budget

        check_budget([spec.scene] * (2 * len(spec.free) + 1), observation.frames[-1] + 1, device, str(spec.source))
        engine = MpmFiniteDifference(spec, observation, fd_step, device, progress)
        return engine, engine, ""
    if engine == "mpm-ad":
        from runout.inverse.mpm_ad import MpmAutodiff

        engine = MpmAutodiff(spec, observation, device)
        return engine, engine, ""
    from runout.inverse.forward import inverse_problem
    from runout.learned.scenes import scene_at_rest
    from runout.learned.training_range import bound_warnings, range_warnings

    if warn is not None:
        lines = range_warnings(learned, scene_at_rest(spec.scene), f"the scene of {spec.source}")
        for p in spec.free:
            lines += bound_warnings(learned, p.name, p.unit, p.lower, p.upper)
        for line in lines:
            warn(line)
    problem = inverse_problem(spec, observation, learned, checkpoint, progress)
    return problem.evaluate, problem, model_identity(model)


def _draw(result: StartResult, observation: Observation, chosen, warn: Log | None) -> None:
    history = result.history
    draw_loss(history, result.out_dir / "loss.png")
    draw_parameters(history, result.out_dir / "parameters.png")
    available = [r.iteration for r in history.iterations]
    iterations, missed = pick_iterations(chosen, available)
    if missed and warn is not None:
        warn(f"--plot-iterations {', '.join(map(str, missed))} not drawn, because the run stopped after iteration {available[-1]}.")
    iterations = iterations or default_iterations(available)
    draw_deposits(history, observation.positions[-1], observation.material_id, observation.moving, iterations,
                  result.out_dir / "deposit.png")


def _write_starts(inversion: InversionResult, out_dir: Path) -> None:
    free = inversion.spec.free
    rows = [
        {"start": k, "folder": r.out_dir.name, "initial": r.start.tolist(), "values": r.values.tolist(),
         "loss": r.loss, "iterations": r.iterations, "evaluations": r.evaluations, "message": r.message}
        for k, r in enumerate(inversion.starts)
    ]
    summary = {"parameters": [p.name for p in free], "true": inversion.best.history.true_values,  # None: unknown
               "data_loss_at_true_m2": inversion.loss_at_truth, "starts": rows, "spread": inversion.spread}
    (out_dir / "starts.json").write_text(json.dumps(summary, indent=1))
    header = ["start", "loss (m^2)", "iterations"] + [f"initial {p.name} ({p.unit})" for p in free]
    header += [f"{p.name} ({p.unit})" for p in free]
    lines = [",".join(header)]
    for row in rows:
        cells = [row["start"], repr(row["loss"]), row["iterations"], *map(repr, row["initial"]), *map(repr, row["values"])]
        lines.append(",".join(str(c) for c in cells))
    (out_dir / "starts.csv").write_text("\n".join(lines) + "\n")
    draw_starts(inversion.starts, out_dir / "starts.png")


def summary_lines(inversion: InversionResult) -> list[str]:
    """The final parameters with their bounds (best start), then the spread over starts, then
    the intervals when they were asked for."""
    best = inversion.best
    lines = [f"final loss {best.loss:.4g} m^2 after {best.iterations} iterations ({best.message})"]
    for p, v in zip(inversion.spec.free, best.values):
        lines.append(f"  {p.name:<32} = {v:10.4g} {p.unit:<8} bounds [{p.lower:g}, {p.upper:g}]")
    if inversion.loss_at_truth is not None:
        truth = ", ".join(f"{p.name} = {v:g} {p.unit}" for p, v in zip(inversion.spec.free, best.history.true_values))
        lines.append(f"at the true values ({truth}): loss {inversion.loss_at_truth:.4g} m^2 (at the answer: {best.loss:.4g} m^2)")
    if len(inversion.starts) > 1:
        lines.append(f"spread over {len(inversion.starts)} starts (min .. max, std, range / bound width):")
        for row in inversion.spread:
            lines.append(
                f"  {row['name']:<32} {row['min']:.4g} .. {row['max']:.4g} {row['unit']}, "
                f"std {row['std']:.3g}, {100 * row['range_of_bounds']:.1f} % of bounds"
            )
        losses = np.array([r.loss for r in inversion.starts])
        lines.append(f"  final losses {losses.min():.4g} .. {losses.max():.4g} m^2")
    if inversion.intervals is not None:
        lines += interval_lines(inversion.intervals)
    return lines


def model_identity(model: str | Path) -> str:
    """The model file a run's history belongs to: its path and the sha256 of its bytes, so a
    run is not resumed on the evaluations of a file since replaced at the same path."""
    path = Path(model).resolve()
    return f"{path} (sha256 {hashlib.sha256(path.read_bytes()).hexdigest()[:16]})"
