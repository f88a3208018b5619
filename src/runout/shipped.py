"""Where runout finds the model it ships, for `runout demo` without --model.

In this order: the file given with --model; the folder that the environment variable
RUNOUT_MODELS names (e.g. a checkout's models/, or a folder of models trained elsewhere); the
copy installed with the package (runout/models/, package data: in a checkout it is a link to
the repository's models/). Never a path relative to a source tree, so an installed runout
finds its model from any working folder.
"""

from __future__ import annotations

import os
from pathlib import Path

from runout.errors import InputError

MODELS_VARIABLE = "RUNOUT_MODELS"
SHIPPED_MODEL = "neural-mpm.pt"  # the learned engine that measures better today (the neural MPM): models/README.md
INSTALLED = Path(__file__).resolve().parent / "models"


def shipped_model(name: str = SHIPPED_MODEL) -> Path:
    """$RUNOUT_MODELS/name when the variable is set, else the installed copy; InputError (one
    sentence) when the file is not where the lookup says."""
    folder = os.environ.get(MODELS_VARIABLE)
    if folder:
        path = Path(folder).expanduser() / name
        if not path.is_file():
            raise InputError(f"{MODELS_VARIABLE}={folder}: {name} is not in that folder; set {MODELS_VARIABLE} to a "
                             f"folder that holds {name}, unset it to use the installed model, or pass --model FILE.")
        return path
    path = INSTALLED / name
    if not path.is_file():
        raise InputError(f"the shipped model {path} is missing (an incomplete install?); reinstall runout, "
                         f"set {MODELS_VARIABLE} to a folder that holds {name}, or pass --model FILE.")
    return path
