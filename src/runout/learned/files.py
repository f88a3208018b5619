"""Reading a learned engine's checkpoint file safely, whichever engine wrote it, and telling
which engine that was; writing one atomically.

Every checkpoint is plain data (tensors, dicts, lists, numbers, strings) and is read with
torch.load(weights_only=True): a file that asks the unpickler for any other object is refused
with one sentence and nothing in it runs. Which engine a file holds: its "engine" entry, or,
for the GNS files written before there were two engines, the GNS format "runout-gns-1".
"""

from __future__ import annotations

import os
import pickle
import re
import warnings
from pathlib import Path

import torch

from runout.errors import InputError
from runout.reading import file_to_read

GNS_FORMAT = "runout-gns-1"


def read_plain(path: str | Path) -> object:
    """The file's contents (tensors on the CPU); InputError for a missing, unreadable or unsafe file."""
    path = file_to_read(path, "checkpoint file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # torch warns about pickle protocols of foreign files
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise InputError(_refusal(path, exc)) from None
    except Exception as exc:  # torch raises many types for a corrupt or foreign file
        raise InputError(f"{path}: not a readable PyTorch checkpoint ({type(exc).__name__}: {first_line(exc)}).") from None


def save_plain(path: str | Path, contents: dict) -> Path:
    """Write a checkpoint's contents atomically (a temporary file, then os.replace), so a run
    killed while saving leaves the previous file whole; every engine's checkpoints go through here."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(contents, tmp)
    os.replace(tmp, path)
    return path


def engine_of(ckpt: object) -> str | None:
    """The engine a checkpoint's contents name ("gns", "neural-mpm"), or None."""
    if not isinstance(ckpt, dict):
        return None
    engine = ckpt.get("engine")
    if isinstance(engine, str):
        return engine
    return "gns" if ckpt.get("format") == GNS_FORMAT else None


def _refusal(path: Path, exc: Exception) -> str:
    """One sentence for a file torch's plain-data unpickler stopped reading."""
    found = re.search(r"GLOBAL (\S+)", str(exc))
    if found:
        return (f"{path}: refused to load, because it holds the Python object '{found.group(1)}' "
                "rather than tensors and plain data (nothing in it was run).")
    detail = re.search(r"WeightsUnpickler error:\s*(.+)", str(exc))
    reason = detail.group(1).strip().rstrip(".") if detail else "not plain data"
    return f"{path}: not a readable PyTorch checkpoint of plain data ({reason}); nothing in it was run."


def first_line(exc: Exception) -> str:
    return str(exc).strip().splitlines()[0].rstrip(".") if str(exc).strip() else "no detail"
