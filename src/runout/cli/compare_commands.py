"""`runout compare`: the MPM and a learned engine on one scene, side by side (the work is
runout.compare.run_compare)."""

from __future__ import annotations

from pathlib import Path

import typer

from runout.cli.app import app
from runout.defaults import MPM_CACHE as DEFAULT_CACHE


@app.command()
def compare(
    scene: Path = typer.Argument(..., help="Scene file (TOML or JSON); both engines fill it at the model's point spacing."),
    model: Path = typer.Option(..., "--model", help="Learned-engine checkpoint (.pt): a GNS or a neural MPM, the file says which."),
    engine: str = typer.Option(None, "--engine", help="gns or neural-mpm: checked against the model file (optional; the file names its engine)."),
    out: Path = typer.Option(..., "--out", help="Output folder: metrics.json, final.png, the animation and predicted/."),
    frames: int = typer.Option(None, "--frames", help="Frames of both runs, frame 0 included (default: the scene's); an engine of frame stride K writes one every K."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda, for both the MPM and the learned engine."),
    cache: Path = typer.Option(DEFAULT_CACHE, "--cache", help="Folder of cached MPM runs, keyed by a hash of the scene's TOML."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Show progress bars."),
    force: bool = typer.Option(False, "--force", help="Replace another command's results in --out (removing, and naming, the files that command wrote and this run does not rewrite; files runout did not write stay)."),
) -> None:
    """Run the MPM and the model's learned engine on SCENE at the model's resolution: runout
    errors of both fronts and of the farthest point, deposit overlap (IoU), position MSE and
    both wall times in metrics.json, the final frames side by side (MPM left, engine right)
    and an animation."""
    from runout import checks
    from runout.cli.gns_commands import check_range
    from runout.compare import run_compare
    from runout.mpm.cache import MpmCache
    from runout.scene.limits import MAX_FRAMES

    check_range("--frames", frames, 1, MAX_FRAMES)  # the least the model needs: run_compare checks it
    checks.device(device)
    result = run_compare(
        scene, model, out, frames, device, MpmCache(cache), force, progress, log=typer.echo, engine=engine,
        warn=lambda line: typer.secho(f"warning: {line}", err=True, fg=typer.colors.YELLOW),
    )
    m = result.metrics
    name = result.label
    for side in ("left", "right", "farthest"):
        r = m[f"runout_{side}_m"]
        ape = "n/a" if r["ape_percent"] is None else f"{r['ape_percent']:.1f} %"
        typer.echo(f"runout {side:<8} MPM {r['truth']:8.1f} m, {name} {r['predicted']:8.1f} m, error {r['error_m']:+.1f} m ({ape})")
    typer.echo(f"deposit IoU {m['deposit_iou']:.3f} on {m['cell_size_m']:g} m cells; position MSE mean "
               f"{m['position_mse_mean_m2']:.4g} m², final {m['position_mse_final_m2']:.4g} m²")
    wall = m["wall_s"]
    mpm = "n/a" if wall["mpm"] is None else f"{wall['mpm']:.1f} s" + (" (cached run)" if wall["mpm_cached"] else "")
    ratio = "" if wall["mpm_over_engine"] is None else f", MPM / {name} = {wall['mpm_over_engine']:.3g}"
    typer.echo(f"wall time MPM {mpm}, {name} {wall['engine']:.1f} s{ratio}")
    typer.echo("wrote " + ", ".join(str(p) + ("/" if p.is_dir() else "") for p in result.files))
