"""The exception types a `runout` command ends with, each mapped to one sentence and an
exit code by runout.cli.exits.

InputError (exit 2): a user-supplied file or value is invalid; its message is a single
sentence naming the file, the field, the value and the allowed range.
RunFailed (exit 1): a run that started on valid input could not finish (it diverged).
Interrupted (exit 130): Ctrl-C; the message says what was saved and how to resume.
"""


class InputError(ValueError):
    """A user-supplied file or value is invalid; the message says what and how to fix it."""


class RunFailed(RuntimeError):
    """A computation on valid input failed (e.g. it diverged); the message says where."""


class RolloutDiverged(RunFailed):
    """A learned engine's rollout produced non-finite positions."""


class Interrupted(Exception):
    """Ctrl-C ended a run; the message says what was saved and how to resume."""
