"""load_engine: the learned engine a checkpoint file holds, whichever it is.

The file names its engine (runout.learned.files.engine_of), so `--model FILE` alone selects
it; `--engine NAME`, where a command still takes it, must agree with the file, or the command
stops with one sentence (exit 2) before anything runs.
"""

from __future__ import annotations

from pathlib import Path

import torch

from runout.errors import InputError
from runout.learned.engine import ENGINE_NAMES, LearnedEngine
from runout.learned.files import engine_of, read_plain


def engine_name(path: str | Path) -> str:
    """The engine a checkpoint file holds ("gns" or "neural-mpm"); InputError for any other file."""
    return _engine_named(read_plain(path), path)


def _engine_named(contents: object, path: str | Path) -> str:
    found = engine_of(contents)
    if found not in ENGINE_NAMES:
        raise InputError(f"{path}: is not a checkpoint of a runout learned engine ({', '.join(ENGINE_NAMES)}); "
                         f"it names {found!r}." if found else
                         f"{path}: is not a checkpoint of a runout learned engine ({', '.join(ENGINE_NAMES)}).")
    return found


def load_engine(path: str | Path, device: str | torch.device = "cpu", expect: str | None = None) -> LearnedEngine:
    """The engine stored in `path`, on `device`, ready to roll out. expect: the engine a command
    was asked for (--engine); a file of another engine is refused with one sentence."""
    if expect is not None and expect not in ENGINE_NAMES:
        raise InputError(f"--engine {expect!r} must be one of {', '.join(ENGINE_NAMES)}.")
    contents = read_plain(path)  # read once: the engine's own checks take these contents
    name = _engine_named(contents, path)
    if expect is not None and expect != name:
        raise InputError(f"{path}: holds a {name} model, but --engine {expect} was asked for; "
                         f"give a {expect} checkpoint or leave --engine out (the file names its engine).")
    if name == "gns":
        from runout.gns.checkpoint import check_checkpoint, simulator_from_checkpoint
        from runout.gns.engine import GnsEngine

        return GnsEngine(simulator_from_checkpoint(check_checkpoint(contents, path), path).to(device).eval())
    from runout.neural_mpm.checkpoint import check_checkpoint, engine_from_checkpoint

    return engine_from_checkpoint(check_checkpoint(contents, path), path).to(device).eval()
