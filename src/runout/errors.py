"""The one exception type for bad user input (scene files, datasets, checkpoints, specs).

Its message is a single sentence naming the file, the field, the value and the allowed
range; the command line prints it and exits with code 2.
"""


class InputError(ValueError):
    """A user-supplied file or value is invalid; the message says what and how to fix it."""
