"""Where results go: checked before any work, never mixing the results of two runs, never
deleting a file runout did not write.

Every command that writes a folder records itself in OUT/.runout.json, with the top-level
names (files and folders) its run writes there. Before any work, `check_folder` refuses
(InputError, one sentence):

- an --out that is an existing file, or lies below one;
- a folder (or, for a new folder, its nearest existing parent) that cannot be written;
- a folder holding another command's results (by its .runout.json, or by the files that
  runout wrote before it had one), unless --force;
- a non-empty folder that runout did not write, even with --force (it is never emptied).

What the same command does with its own folder is its mode: "replace" (mpm, rollout,
compare, demo, families, validate: the new results replace the old), "resume" (generate,
train, invert: the run continues; --force starts it afresh) or "add" (evaluate: each study
adds its own subfolder). When results are replaced (--force on another command's folder, or
mode "replace"), `claim` first removes the previous run's names that the new run will not
rewrite, so a folder never looks like a mix of runs; --force on a resumable run removes all
of them. Only names the marker lists are ever removed: a user's notes, a scene file or a
nested run's folder beside the results stay. A marker or folder from before the marker
listed its names is read conservatively: only names that command is known to write (KNOWN)
are removed. --force names what it removes on stderr before removing it.

Pictures (`check_picture`) must be named with a .png, .pdf or .svg suffix, so what is
written is exactly the file named.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from fnmatch import fnmatchcase
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
# Every top-level name (fnmatch pattern) each command writes: what a marker without the list
# of names (or a LEGACY folder) may lose on replace. Anything else there is kept.
KNOWN = {
    "mpm": ("trajectory.npz", "metadata.json", "initial.png", "final.png", "animation.gif", "vtk"),
    "rollout": ("trajectory.npz", "metadata.json", "snapshots.png", "metrics.json", "position_mse.png",
                "animation.gif", "animation.mp4", "vtk"),
    "compare": ("metrics.json", "final.png", "gns", "animation.gif", "animation.mp4"),
    "demo": ("forward", "inverse"),
    "families": ("[abcd]_[0-9][0-9][0-9].toml", "column_[0-9][0-9][0-9].toml"),
    "validate": ("results.json", "validation.md", "cut_phi*.png", "column_*.png", "dry_column_*.png",
                 "griffiths_lane_*.png", "block_incline_*.png", "convergence_*.png"),
    "generate": ("generate.json", "scenes", "parts", "train.npz", "valid.npz", "test.npz", "metadata.json"),
    "train": ("checkpoint.pt", "best.pt", "log.jsonl", "tensorboard"),
    "invert": ("history.json", "history.csv", "loss.png", "parameters.png", "deposit.png", "deposits",
               "start_[0-9][0-9]", "starts.json", "starts.csv", "starts.png"),
    "evaluate": ("columns", "slope", "diagnostics", "inverse", "sensitivity"),
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
    """Create the folder, remove the previous run's names this run would not rewrite (all of
    them on --force over a resumable run), and record the command and the names it writes.
    Nothing the previous run did not write is touched; --force names what it removes first."""
    path = folder.path
    path.mkdir(parents=True, exist_ok=True)
    previous = _written(path, folder.owner)
    own = folder.owner == folder.command
    if own and (folder.mode == "add" or (folder.mode == "resume" and not folder.force)):
        remove, kept = set(), previous  # the run continues
    elif own and folder.mode == "resume":
        remove, kept = previous, set()  # --force: start afresh
    else:
        remove, kept = previous - folder.writes, set()  # replacing results
    if remove and folder.force:
        print(f"--force removes {', '.join(sorted(remove))} from {path} (the results of `runout {folder.owner}`; "
              "files runout did not write stay)", file=sys.stderr)
    for name in remove:
        entry = path / name
        shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
    _write_marker(path, folder.command, kept | folder.writes)
    return path


def record(path: str | Path, names) -> None:
    """Add to OUT/.runout.json names a run wrote that it could not name before it ran."""
    path = Path(path)
    data = _read_marker(path)
    _write_marker(path, data["command"], set(data["written"] or ()) | set(names))


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


def write_atomic(path: Path, text: str) -> None:
    """Write then rename, so a killed process never leaves a half-written file."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _owner(path: Path) -> str | None:
    """The command whose results the folder holds, None if empty or new, 'foreign' otherwise."""
    if not path.is_dir() or not any(path.iterdir()):
        return None
    if (path / MARKER).is_file():
        data = _read_marker(path)
        return "foreign" if data is None else data["command"]
    for command, signatures in LEGACY.items():
        if any(all((path / name).exists() for name in names) for names in signatures):
            return command
    return "foreign"


def _read_marker(path: Path) -> dict | None:
    """OUT/.runout.json as {"command": str, "written": list of names, or None when it predates
    the list}; None when it is missing or not a marker runout wrote."""
    try:
        data = json.loads((path / MARKER).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("command"), str):
        return None
    written = data.get("written")
    if written is not None and not (isinstance(written, list) and all(isinstance(n, str) for n in written)):
        return None
    return {"command": data["command"], "written": written}


def _written(path: Path, owner: str | None) -> set[str]:
    """Names now in the folder that the runs of `owner` wrote there: those its marker lists,
    or, for a marker or folder from before the list, those that command is known to write."""
    if owner is None:
        return set()
    present = {entry.name for entry in path.iterdir()} - {MARKER}  # plain names only: nothing outside is reached
    data = _read_marker(path)
    if data is not None and data["written"] is not None:
        return present & set(data["written"])
    return {name for name in present if any(fnmatchcase(name, pattern) for pattern in KNOWN.get(owner, ()))}


def _write_marker(path: Path, command: str, written) -> None:
    marker = {"command": command, "runout": runout.__version__, "written": sorted(written)}
    write_atomic(path / MARKER, json.dumps(marker) + "\n")


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
