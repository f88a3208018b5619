"""Command line entry point: `runout ...` and `python -m runout ...`.

Every failure ends with one sentence and a non-zero exit code (runout.cli.exits): 2 for bad
input or usage, 1 for a run that failed, 130 for Ctrl-C, start-up (these imports) included.
"""

import sys

STARTUP_INTERRUPTED = "error: interrupted (Ctrl-C) while runout was starting; nothing was written.\n"

try:
    from runout.cli.app import app
    from runout.cli import mpm_commands  # noqa: F401  (registers mpm, show)
    from runout.cli import gns_commands  # noqa: F401
    from runout.cli import inverse_commands  # noqa: F401
    from runout.cli import data_commands  # noqa: F401
    from runout.cli import demo_commands  # noqa: F401
    from runout.cli import evaluate_commands  # noqa: F401
    from runout.cli import compare_commands  # noqa: F401
    from runout.cli import validate_commands  # noqa: F401
    from runout.cli import hazard_commands  # noqa: F401
    from runout.cli.exits import EXIT_INTERRUPTED, run
    from runout.threads import choose_threads
except KeyboardInterrupt:  # Ctrl-C while the command line loads: exit 130, not a traceback
    sys.stderr.write(STARTUP_INTERRUPTED)
    sys.exit(130)


def main(args: list[str] | None = None) -> None:
    """`runout ARGS...` (sys.argv when args is None); returns on success, else exits with
    the failure's code. A fresh process (torch not imported yet) computes on the cores other
    processes leave idle (runout.threads)."""
    try:
        if "torch" not in sys.modules:
            choose_threads()
    except KeyboardInterrupt:
        sys.stderr.write(STARTUP_INTERRUPTED)
        sys.exit(EXIT_INTERRUPTED)
    code = run(app, args)
    if code:
        sys.exit(code)
