"""Where results go: checked before any work, never mixing the results of two runs.

Every command that writes a folder records itself in OUT/.runout.json. Before any work,
`check_folder` refuses (InputError, one sentence):

- an --out that is an existing file, or lies below one;
- a folder (or, for a new folder, its nearest existing parent) that cannot be written;
- a folder holding another command's results (by its .runout.json, or by the files that
  runout wrote before it had one), unless --force;
- a non-empty folder that runout did not write, even with --force (it is never emptied).

What the same command does with its own folder is its mode: "replace" (mpm, rollout,
compare, demo, families: the new results replace the old), "resume" (generate, train,
invert: the run continues; --force starts it afresh) or "add" (evaluate: each study adds
its own subfolder). When results are replaced (--force on another command's folder, or mode
"replace"), `claim` first removes whatever in the folder the new run would not rewrite,
so a folder never looks like a mix of runs.

Pictures (`check_picture`) must be named with a .png, .pdf or .svg suffix, so what is
written is exactly the file named.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import runout
from runout.errors import InputError

MARKER = ".runout.json"
PICTURE_SUFFIXES = (".png", ".pdf", ".svg")
# Folders written before the marker existed, recognised by files only that command writes
# (each entry: names that must all be there).
LEGACY = {
    "generate": (("generate.json",),),
    "train": (("checkpoint.pt",), ("log.jsonl",)),
    "invert": (("history.json",), ("starts.json",)),
    "mpm": (("initial.png", "trajectory.npz"),),
    "rollout": (("metrics.json", "trajectory.npz"),),
    "demo": (("forward", "inverse"),),
    "evaluate": tuple((f"{study}/summary.json",) for study in ("columns", "slope", "diagnostics", "inverse", "sensitivity")),
}


@dataclass(frozen=True)
class OutputFolder:
    """A checked --out folder: who writes it, what the run writes there, how it treats its own."""

    path: Path
    command: str
    writes: frozenset[str]  # top-level names the run writes (files or folders)
    mode: str  # "replace", "resume" or "add"
    force: bool
    owner: str | None  # the command whose results are there now (None: empty or new)


MODES = ("replace", "resume", "add")


def check_folder(
    path: str | Path, command: str, writes=(), mode: str = "replace", force: bool = False, option: str = "--out"
) -> OutputFolder:
    """Check that `path` may take this run's results; raise InputError if not. Changes nothing."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r} is not one of {MODES}")
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path} is an existing file; give a folder for the results.")
    _check_writable(path, option)
    owner = _owner(path)
    if owner == "foreign":
        shown = ", ".join(sorted(p.name for p in path.iterdir())[:3])
        raise InputError(
            f"{option} {path} holds files runout did not write ({shown}); give an empty or new folder "
            "(--force replaces only the results of runout commands)."
        )
    if owner not in (None, command) and not force:
        raise InputError(
            f"{option} {path} holds the results of `runout {owner}`; choose another folder or pass --force to replace them."
        )
    return OutputFolder(path, command, frozenset(writes), mode, force, owner)


def claim(folder: OutputFolder) -> Path:
    """Create the folder, remove what a replacing run would not rewrite, and record the command."""
    path = folder.path
    path.mkdir(parents=True, exist_ok=True)
    own = folder.owner == folder.command
    if folder.owner is None or (own and folder.mode == "add") or (own and folder.mode == "resume" and not folder.force):
        keep = None  # nothing to remove
    elif own and folder.mode == "resume":
        keep = set()  # --force: start afresh
    else:
        keep = folder.writes  # replacing results: remove what this run does not rewrite
    if keep is not None:
        for entry in path.iterdir():
            if entry.name not in keep and entry.name != MARKER:
                shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
    record = {"command": folder.command, "runout": runout.__version__}
    (path / MARKER).write_text(json.dumps(record) + "\n")
    return path


def prepare_folder(path, command: str, writes=(), mode: str = "replace", force: bool = False, option="--out") -> Path:
    """check_folder, then claim: for commands that write as they go."""
    return claim(check_folder(path, command, writes, mode, force, option))


def check_picture(path: str | Path, option: str = "--out") -> Path:
    """A picture file to write: a known suffix, not a folder, in a folder that can be written."""
    path = Path(path)
    if path.suffix.lower() not in PICTURE_SUFFIXES:
        raise InputError(
            f"{option} {path} must name a picture file ending in {', '.join(PICTURE_SUFFIXES)}, such as {path.name or 'scene'}.png."
        )
    if path.is_dir():
        raise InputError(f"{option} {path} is an existing folder; name a picture file such as {path / 'scene.png'}.")
    _check_writable(path.parent, option)
    return path


def _owner(path: Path) -> str | None:
    """The command whose results the folder holds, None if empty or new, 'foreign' otherwise."""
    if not path.is_dir() or not any(path.iterdir()):
        return None
    marker = path / MARKER
    if marker.is_file():
        try:
            return str(json.loads(marker.read_text())["command"])
        except (ValueError, KeyError, TypeError):
            return "foreign"
    for command, signatures in LEGACY.items():
        if any(all((path / name).exists() for name in names) for names in signatures):
            return command
    return "foreign"


def _check_writable(path: Path, option: str) -> None:
    """The folder (or its nearest existing ancestor, where it would be created) takes a file."""
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{option} {path} cannot be created, because {existing} is a file.")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".runout-probe-")
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot write in {existing} ({exc.strerror or exc}).") from None
    os.close(fd)
    os.unlink(probe)
