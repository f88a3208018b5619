"""Command line entry point: `runout ...` and `python -m runout ...`.

Bad input (runout.errors.InputError) is printed as one sentence and exits with code 2.
"""

import sys

import typer

from runout.cli.app import app
from runout.cli import mpm_commands  # noqa: F401  (registers mpm, show)
from runout.cli import gns_commands  # noqa: F401
from runout.cli import inverse_commands  # noqa: F401
from runout.cli import data_commands  # noqa: F401
from runout.cli import demo_commands  # noqa: F401
from runout.cli import evaluate_commands  # noqa: F401
from runout.errors import InputError


def main() -> None:
    try:
        app(standalone_mode=False)
    except InputError as exc:
        typer.secho(f"error: {exc}", err=True, fg=typer.colors.RED)
        sys.exit(2)
    except typer.Abort:
        typer.echo("aborted", err=True)
        sys.exit(1)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except Exception as exc:  # click usage errors carry their own exit code (2)
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            sys.exit(exc.exit_code)
        raise
