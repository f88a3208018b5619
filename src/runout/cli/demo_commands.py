"""`runout demo`: a forward GNS runout and an inverse back-calculation with the shipped model
(the work is runout.demo.run_demo)."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from runout.cli.app import app
from runout.scene import EXAMPLES

REPO = Path(__file__).resolve().parents[3]


@app.command()
def demo(
    out: Path = typer.Option(Path("out/demo"), "--out", help="Output folder (created)."),
    model: Path = typer.Option(REPO / "models" / "slope.pt", "--model", help="GNS checkpoint with cohesion input."),
    examples: Path = typer.Option(EXAMPLES, "--examples", help="Folder holding four_layer_slope.toml and small_dam.toml."),
    quick: bool = typer.Option(False, "--quick", hidden=True, help="Few frames and iterations: a wiring check for tests."),
    force: bool = typer.Option(False, "--force", help="Replace another command's results in --out."),
) -> None:
    """Forward runout of the four-layer slope and inverse back-calculation of one strength on a
    small dam, with the shipped GNS; prints where the pictures are (a few minutes on a CPU)."""
    from runout.demo import run_demo

    t0 = time.perf_counter()
    pictures = run_demo(out, model, examples, quick, force, log=typer.echo)
    typer.echo(f"demo done in {time.perf_counter() - t0:.0f} s. Results:")
    for path in pictures:
        typer.echo(f"  {path}")
