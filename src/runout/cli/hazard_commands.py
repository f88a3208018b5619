"""`runout hazard`: runout as a probability over uncertain soil strengths."""

from __future__ import annotations

from pathlib import Path

import typer

from runout.cli.app import app


@app.command()
def hazard(
    spec: Path = typer.Argument(..., help="Hazard spec (TOML), see docs/hazard.md."),
    out: Path = typer.Option(..., "--out", help="Study folder; rerun the same command to resume."),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda or cuda:K."),
    shard: str = typer.Option(None, "--shard", help="i/n: run only batches j with j mod n = i; join with --merge."),
    merge: list[Path] = typer.Option(None, "--merge", help="Shard folders of this spec to join into --out (runs nothing)."),
    force: bool = typer.Option(False, "--force", help="Start afresh in --out, removing a previous study or another command's results there."),
) -> None:
    """Run a Monte Carlo study of runout over uncertain phi and c on the batched MPM: exceedance
    maps P(thickness > h), each front's runout distribution, rank correlations, pictures."""
    from runout import checks
    from runout.errors import Interrupted
    from runout.generate import parse_shard
    from runout.hazard import STUDY_FILES, load_spec, merge_study, run_hazard
    from runout.outputs import check_folder, claim

    checks.device(device)
    where = parse_shard(shard) if shard else (0, 1)
    study = load_spec(spec)
    folder = check_folder(out, "hazard", STUDY_FILES, mode="resume", force=force, inputs={"the spec": spec})
    if where[0] == 0:  # one process prepares a folder that several shards share
        claim(folder)
    if merge:
        summary = merge_study(study, merge, out)
    else:
        try:
            summary = run_hazard(study, out, where, device)
        except KeyboardInterrupt:
            raise Interrupted(f"the finished batches are in {out / 'parts'}, and the same command resumes from them.") from None
    if summary is None:
        typer.echo(f"shard {where[0]}/{where[1]} done; join the shards with `runout hazard {spec} --merge DIR ... --out DIR`")
        return
    for front, s in summary["fronts"].items():
        settled = "settled to 1 %" if s["p95_settled_to_1_percent"] else f"about {s['realisations_to_settle_p95']} realisations would settle it to 1 %"
        typer.echo(f"{front} front runout: P5 {s['p5_m']:.1f} m, P50 {s['p50_m']:.1f} m, P95 {s['p95_m']:.1f} "
                   f"± {s['p95_standard_error_m'] or 0:.1f} m (bootstrap s.e.; {settled})")
    typer.echo(f"wrote {out}/summary.json, exceedance.csv, exceedance.png, realisations.csv, runouts.png")
