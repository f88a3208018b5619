"""The `runout` Typer application; command groups register themselves on `app`."""

import typer

from runout import __version__

app = typer.Typer(
    name="runout",
    help="Slope runout: batched MPM, learned engines (GNS, neural MPM), and inverse back-calculation of soil strengths.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(asked: bool) -> None:
    if asked:
        typer.echo(f"runout {__version__}")
        raise typer.Exit()


@app.callback()
def options(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                 help="Print runout's version and exit."),
) -> None:
    """Options before the command."""
