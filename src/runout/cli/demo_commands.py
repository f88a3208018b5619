"""`runout demo`: the MPM's forward runout and back-calculation, then the learned engine's on the
same scenes (the work is runout.demo.run_demo; the model lookup runout.shipped)."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from runout.cli.app import app
from runout.scene import EXAMPLES


@app.command()
def demo(
    out: Path = typer.Option(Path("out/demo"), "--out", help="Output folder (created)."),
    model: Path = typer.Option(
        None, "--model", show_default=False,
        help="Learned engine's checkpoint (GNS or neural MPM) with a cohesion input. Default: neural-mpm.pt in the "
             "folder $RUNOUT_MODELS names, else the model installed with runout."),
    examples: Path = typer.Option(EXAMPLES, "--examples", help="Folder holding four_layer_slope.toml and small_dam.toml."),
    quick: bool = typer.Option(False, "--quick", hidden=True, help="Few frames and iterations: a wiring check for tests."),
    force: bool = typer.Option(False, "--force", help="Replace another command's results in --out."),
) -> None:
    """What runout computes right, then what a learned engine makes of it: the MPM's forward
    runout of the paper's four-layer slope and its back-calculation of a dam's soil strength,
    then the learned engine's, each with its measured error (a few minutes on a CPU)."""
    from runout.demo import run_demo
    from runout.shipped import shipped_model

    t0 = time.perf_counter()
    pictures = run_demo(out, model or shipped_model(), examples, quick, force, log=typer.echo)
    typer.echo(f"demo done in {time.perf_counter() - t0:.0f} s. Pictures:")
    for path in pictures:
        typer.echo(f"  {path}")
