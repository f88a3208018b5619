"""`runout validate`: the MPM against theory, experiments and the paper's MPM."""

from __future__ import annotations

from pathlib import Path

import typer

from runout.cli.app import app


@app.command()
def validate(
    out: Path = typer.Option(..., "--out", help="Folder for the pictures, results.json and validation.md."),
    quick: bool = typer.Option(False, "--quick", help="Only the fast checks, at 8 m cells (about a minute)."),
    case: list[str] = typer.Option(None, "--case", help="Run only these cases (repeatable): cuts, paper_columns, "
                                   "dry_columns, griffiths_lane, incline, convergence."),
    report: Path = typer.Option(None, "--report", help="Write the Markdown report here instead of OUT/validation.md."),
    force: bool = typer.Option(False, "--force", help="Replace another command's results in --out."),
) -> None:
    """Run the MPM validation cases with the solver's defaults: vertical cuts against the limit
    theorems, the paper's three columns, dry columns against the 2D experiments, Griffiths &
    Lane's slope, a block on an incline, and time-step / point-density convergence."""
    from runout.errors import InputError
    from runout.outputs import check_folder, claim, record
    from runout.validate import CASES, run_validation

    unknown = [c for c in (case or []) if c not in CASES]
    if unknown:
        raise InputError(f"--case {unknown[0]!r} is not a validation case; choose from {', '.join(CASES)}.")
    writes = ("results.json",) + (("validation.md",) if report is None else ())
    folder = check_folder(out, "validate", writes, mode="replace", force=force)
    claim(folder)
    parts = ["runout validate"] + (["--quick"] if quick else []) + [f"--case {c}" for c in case or []]
    parts += [f"--out {out}"] + ([f"--report {report}"] if report else [])
    results = run_validation(out, quick=quick, cases=case or None, report=report, command=" ".join(parts),
                             progress=typer.echo)
    record(out, [Path(r.figure).name for r in results])  # one picture per check, named by its result
    met = sum(r.met for r in results)
    typer.echo(f"{met} of {len(results)} checks met; wrote {report or out / 'validation.md'}")
