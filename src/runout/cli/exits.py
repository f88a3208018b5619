"""How every `runout` command ends: one sentence on stderr and an exit code.

    0    success
    1    a run that failed on valid input: it diverged, ran out of memory, the disk filled
         up, or the system refused a file operation
    2    bad input: an invalid file or value (runout.errors.InputError) or a usage error
         (unknown option, missing argument)
    130  Ctrl-C, after the command saved what a rerun resumes from (runout.errors.Interrupted)

The command's return value and typer's own exit codes are passed on, never dropped.
"""

from __future__ import annotations

import errno
import sys

import typer

from runout.errors import InputError, Interrupted, RunFailed

EXIT_OK, EXIT_FAILED, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def run(app: typer.Typer, args: list[str] | None = None) -> int:
    """Run the command line and return its exit code, having printed one sentence on failure."""
    try:
        code = app(args=args, prog_name="runout", standalone_mode=False)
    except InputError as exc:
        return _fail(str(exc), EXIT_INPUT)
    except Interrupted as exc:
        return _fail(f"interrupted: {exc}", EXIT_INTERRUPTED)
    except (KeyboardInterrupt, typer.Abort):
        code = EXIT_INTERRUPTED
    except typer.TyperException as exc:  # usage errors of typer's command-line parser
        return _usage(exc)
    except RunFailed as exc:
        return _fail(str(exc), EXIT_FAILED)
    except Exception as exc:
        sentence = _system_failure(exc)
        if sentence is None:
            raise  # a bug: keep the traceback
        return _fail(sentence, EXIT_FAILED)
    if code == EXIT_INTERRUPTED:  # typer turns a Ctrl-C outside our handlers into exit 130
        return _fail("interrupted (Ctrl-C) before the command finished; its outputs are incomplete.", EXIT_INTERRUPTED)
    return code if isinstance(code, int) else EXIT_OK


def _fail(sentence: str, code: int) -> int:
    typer.secho(f"error: {sentence}", err=True, fg=typer.colors.RED)
    return code


def _usage(exc: typer.TyperException) -> int:
    code = getattr(exc, "exit_code", EXIT_INPUT)
    if type(exc).__name__ == "NoArgsIsHelpError":  # `runout` or `runout evaluate` alone: the help
        exc.show()
        return code
    ctx = getattr(exc, "ctx", None)
    where = f" (see `{ctx.command_path} --help`)" if ctx is not None else ""
    message = " ".join(exc.format_message().split()).rstrip(".")
    return _fail(f"{message}{where}.", code or EXIT_INPUT)


def _system_failure(exc: Exception) -> str | None:
    """One sentence for out-of-memory and OS failures, or None for anything else."""
    torch = sys.modules.get("torch")  # a torch error can only come from an imported torch
    if isinstance(exc, MemoryError) or (torch is not None and isinstance(exc, torch.OutOfMemoryError)) or (
        isinstance(exc, RuntimeError) and "can't allocate memory" in str(exc)
    ):
        return ("ran out of memory; use fewer points (a coarser cell_size or a smaller domain), "
                "fewer frames or a smaller batch.")
    if isinstance(exc, OSError):
        where = f" for {exc.filename}" if exc.filename else ""
        if exc.errno == errno.ENOSPC:
            return f"no space left on the disk{where}; free some space and run the command again."
        reason = exc.strerror or str(exc) or type(exc).__name__
        return f"the system refused a file operation{where} ({reason}).".replace("..", ".")
    return None
