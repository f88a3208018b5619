"""The `runout` Typer application; command groups register themselves on `app`."""

import typer

app = typer.Typer(
    name="runout",
    help="Slope runout: batched MPM, Graph Network Simulator, and inverse back-calculation of soil strengths.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
