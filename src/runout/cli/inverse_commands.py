"""`runout invert`: back-calculate material strengths from an observed runout."""

from __future__ import annotations

from pathlib import Path

import typer

from runout.cli.app import app


@app.command()
def invert(
    spec: Path = typer.Argument(..., help="Inverse spec (TOML), see docs/inverse-format.md."),
    model: Path = typer.Option(None, "--model", help="Learned-engine checkpoint: a GNS or a neural MPM, the file says which (needed unless --engine mpm-ad or mpm-fd)."),
    out: Path = typer.Option(..., "--out", help="Output folder; a run killed part-way resumes from it."),
    device: str = typer.Option("cpu", help="cpu or cuda."),
    starts: int = typer.Option(1, help="Starting points: the spec's initial values, then a Latin hypercube (seed 0)."),
    engine: str = typer.Option(None, help="gns or neural-mpm (autodiff through the model's rollout; default: the engine --model holds), mpm-fd (MPM runs, central differences) or mpm-ad (autodiff through the MPM)."),
    fd_step: float = typer.Option(0.01, help="Finite-difference step as a fraction of each parameter's bounds: mpm-fd's gradient, and every engine's Jacobian with --uncertainty."),
    checkpoint: bool = typer.Option(True, help="Recompute each rollout step in the backward pass (much less memory)."),
    plot_iterations: str = typer.Option(None, help="Iterations to draw in deposit.png, e.g. '0,1,last' (default: first, second, middle, last)."),
    force: bool = typer.Option(False, "--force", help="Start afresh in --out, removing a previous history or another command's results there."),
    uncertainty: bool = typer.Option(False, "--uncertainty", help="Then intervals on the answer (Gauss-Newton covariance, noise estimated from the residuals), their correlations and the loss along each parameter: uncertainty.json, profile.png. A finished run is not redone."),
    confidence: float = typer.Option(None, help="With --uncertainty: the intervals' confidence, in (0, 1) (default 0.9)."),
) -> None:
    """Fit the spec's free material parameters (phi in degrees, c in kPa) to the target runout
    with L-BFGS-B inside their bounds; writes history.csv, history.json, loss.png,
    parameters.png and deposit.png, and prints the answer with its bounds (with --uncertainty,
    also its intervals: `c[m1] = 40.1 ± 1.3 kPa (90 %)`), and the loss at the true values when
    the target names them. A learned engine fills the scene at
    the model's point spacing (the target must be a run at that spacing)."""
    from runout import checks
    from runout.errors import Interrupted, RolloutDiverged, RunFailed
    from runout.errors import InputError
    from runout.inverse import invert as run_inversion, summary_lines
    from runout.inverse.intervals import DEFAULT_CONFIDENCE, check_confidence

    checks.device(device)
    if confidence is not None:
        check_confidence(confidence)
        if not uncertainty:
            raise InputError(f"--confidence {confidence:g} applies only with --uncertainty; add it or leave --confidence out.")
    try:
        result = run_inversion(
            spec, out, model=model, device=device, starts=starts, engine=engine, fd_step=fd_step,
            checkpoint=checkpoint, plot_iterations=plot_iterations, log=typer.echo, progress=True,
            warn=lambda line: typer.secho(f"warning: {line}", err=True, fg=typer.colors.YELLOW), force=force,
            uncertainty=uncertainty, confidence=DEFAULT_CONFIDENCE if confidence is None else confidence,
        )
    except RolloutDiverged as exc:
        raise RunFailed(f"{str(exc).rstrip('.')}; the history so far is in {out}.") from None
    except KeyboardInterrupt:
        raise Interrupted(f"the evaluations so far are in {out}, and the same command resumes from them.") from None
    for line in summary_lines(result):
        typer.echo(line)
    where = f"{out}/start_*/" if starts > 1 else f"{out}/"
    typer.echo(f"wrote {where}history.csv, history.json, loss.png, parameters.png, deposit.png"
               + (f"; {out}/starts.json, starts.csv, starts.png" if starts > 1 else "")
               + (f"; {out}/uncertainty.json, profile.png" if uncertainty else ""))
