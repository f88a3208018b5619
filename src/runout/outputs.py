"""Where results go: checked before any work, never mixing the results of two runs, never
deleting a file runout did not write.

Every command that writes a folder records itself in OUT/.runout.json, with the top-level
names (files and folders) its run writes there. Before any work, `check_folder` refuses
(InputError, one sentence):

- an --out that is an existing file, or lies below one, or a symbolic link that leads nowhere;
- an --out that is one of the command's inputs, lies inside one or holds one (a dataset, a
  target trajectory, the scene's own folder), even with --force;
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
nested run's folder beside the results stay. A listed folder loses only the files its command
writes there (INSIDE) and goes once nothing else is left in it; a user's file inside stays. A
marker or folder from before the marker listed its names is read conservatively: only names
that command is known to write (KNOWN) are removed. --force names what it removes on stderr
before removing it.

Pictures (`check_picture`) must be named with a .png, .pdf or .svg suffix, so what is
written is exactly the file named.
"""

from __future__ import annotations

import errno
import json
import os
import sys
import tempfile
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path

import runout
from runout.errors import InputError
from runout.reading import broken_link, read_json

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
    "train": ("checkpoint.pt", "best.pt", "log.jsonl", "train.log.jsonl", "tensorboard"),
    "invert": ("history.json", "history.csv", "loss.png", "parameters.png", "deposit.png", "deposits",
               "start_[0-9][0-9]", "starts.json", "starts.csv", "starts.png", "uncertainty.json", "profile.png"),
    "evaluate": ("columns", "slope", "diagnostics", "inverse", "sensitivity"),
    "hazard": ("hazard.json", "parts", "realisations.csv", "realisations.json", "exceedance.csv", "runout_cdf.csv",
               "summary.json", "exceedance.png", "runouts.png"),
}
# What each command writes inside the folders it lists (fnmatch patterns of paths relative to the
# folder, keyed by the folder's name): a stale folder loses these files and the runs nested in it
# that a pattern names, and goes only when nothing else is left in it. A folder with no entry here
# (evaluate's studies) is kept whole.
_TRAJECTORY = ("trajectory.npz", "trajectory.tmp.npz", "metadata.json")
_MPM_CACHE = tuple(f"mpm_*/{name}" for name in (*_TRAJECTORY, "scene.toml"))
_START = ("history.json", "history.csv", "loss.png", "parameters.png", "deposit.png", "deposits/eval_[0-9]*.npy*")
_VTK = {"vtk": ("frame_[0-9][0-9][0-9][0-9][0-9].vtu", "trajectory.pvd")}
INSIDE = {
    "mpm": _VTK,
    "rollout": _VTK,
    "compare": {"gns": _TRAJECTORY},
    "demo": {"forward": ("metrics.json", "animation.gif", "final.png", *_MPM_CACHE),
             "inverse": ("scene.toml", "spec.toml", "result", "mpm_ad", *_MPM_CACHE)},
    "generate": {"scenes": ("scene_[0-9]*.toml",), "parts": ("part_[0-9]*.npz",)},  # and part_*.tmp.npz, being written
    "train": {"snapshots": ("step-[0-9]*.pt", "step-[0-9]*.pt.tmp"), "tensorboard": ("events.out.tfevents.*",)},
    "invert": {"deposits": ("eval_[0-9]*.npy*",), "start_[0-9][0-9]": _START},
    "hazard": {"parts": ("part_[0-9]*.npz",)},  # and part_*.tmp.npz, being written
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
    path: str | Path, command: str, writes=(), mode: str = "replace", force: bool = False, option: str = "--out",
    inputs: dict | None = None,
) -> OutputFolder:
    """Check that `path` may take this run's results and lies apart from the command's `inputs`
    ({what it is, e.g. "--data": path}; None paths are skipped); raise InputError if not. Changes nothing."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r} is not one of {MODES}")
    path = Path(path)
    link = broken_link(path)
    if link is not None:
        raise InputError(f"{option} {path} is {link}; give a folder for the results.")
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path} is an existing file; give a folder for the results.")
    _check_apart(path, {label: p for label, p in (inputs or {}).items() if p is not None}, option)
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
    remove = {name for name in remove if _removable(path / name, folder.owner)}  # the others stay whole
    if remove and folder.force:
        print(f"--force removes {', '.join(sorted(remove))} from {path} (the results of `runout {folder.owner}`; "
              "files runout did not write stay)", file=sys.stderr)
    for name in remove:
        _remove(path / name, folder.owner)
    _write_marker(path, folder.command, kept | folder.writes)
    return path


def record(path: str | Path, names) -> None:
    """Add to OUT/.runout.json names a run wrote that it could not name before it ran."""
    path = Path(path)
    data = _read_marker(path)
    _write_marker(path, data["command"], set(data["written"] or ()) | set(names))


def prepare_folder(path, command: str, writes=(), mode: str = "replace", force: bool = False, option="--out",
                   inputs=None) -> Path:
    """check_folder, then claim: for commands that write as they go."""
    return claim(check_folder(path, command, writes, mode, force, option, inputs))


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
        data = read_json(path / MARKER, "marker")
    except (InputError, OSError):
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


def _remove(entry: Path, owner: str) -> None:
    """Remove a name the runs of `owner` wrote: a file or link itself, a nested run by its own
    marker, a folder only of the files `owner` writes there (INSIDE) and then, if nothing else
    is left in it, the folder."""
    if entry.is_symlink() or not entry.is_dir():
        entry.unlink()
    elif _read_marker(entry) is not None:
        _remove_run(entry)
    else:
        _clear(entry, _inside(owner, entry.name), "", mine=True)


def _inside(owner: str, name: str) -> tuple[str, ...] | None:
    """The patterns of what `owner` writes in its folder `name`; None when not known file by file."""
    return next((p for folder, p in INSIDE.get(owner, {}).items() if fnmatchcase(name, folder)), None)


def _removable(entry: Path, owner: str) -> bool:
    """Whether `_remove` knows what of `entry` the runs of `owner` wrote."""
    return entry.is_symlink() or not entry.is_dir() or _read_marker(entry) is not None or _inside(owner, entry.name) is not None


def _remove_run(folder: Path) -> None:
    """A run folder nested in results: the names its own marker lists, its marker, then the folder if empty."""
    owner = _read_marker(folder)["command"]
    for name in _written(folder, owner):
        _remove(folder / name, owner)
    (folder / MARKER).unlink()
    _rmdir_if_empty(folder)


def _clear(folder: Path, patterns: tuple[str, ...], prefix: str, mine: bool) -> bool:
    """Remove the files below `folder` whose path (prefix + relative path) matches a pattern, and
    the nested runs a pattern names; then `folder` if it is `mine` or lost files and is empty.
    Returns whether anything was removed. Links are removed, never followed."""
    removed = False
    for entry in list(folder.iterdir()):
        relative = prefix + entry.name
        ours = any(fnmatchcase(relative, p) for p in patterns)
        if entry.is_dir() and not entry.is_symlink():
            if _read_marker(entry) is None:
                removed |= _clear(entry, patterns, relative + "/", ours)
            elif ours:
                _remove_run(entry)
                removed = True
        elif ours:
            entry.unlink()
            removed = True
    if mine or removed:
        _rmdir_if_empty(folder)
    return removed


def _rmdir_if_empty(folder: Path) -> None:
    if not any(folder.iterdir()):
        folder.rmdir()


def _write_marker(path: Path, command: str, written) -> None:
    marker = {"command": command, "runout": runout.__version__, "written": sorted(written)}
    write_atomic(path / MARKER, json.dumps(marker) + "\n")


def _check_apart(path: Path, inputs: dict, option: str) -> None:
    """InputError when the results folder is one of the command's inputs, lies inside one or
    holds one: --force or a re-run there could remove what the command reads."""
    out = Path(os.path.realpath(path))
    for label, given in inputs.items():
        where = Path(os.path.realpath(given))
        relation = "is" if out == where else "lies inside" if where in out.parents else "holds" if out in where.parents else None
        if relation is not None:
            raise InputError(f"{option} {path} {relation} {label} {given}; give a results folder apart from the command's inputs.")


def _check_writable(path: Path, option: str) -> None:
    """The folder (or its nearest existing ancestor, where it would be created) takes a file."""
    existing = path
    while not existing.exists() and existing != existing.parent:
        link = broken_link(existing)
        if link is not None:
            raise InputError(f"{option} {path} cannot be created, because {existing} is {link}.")
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{option} {path} cannot be created, because {existing} is a file.")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".runout-probe-")
    except OSError as exc:
        kind = "a read-only folder" if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS) else "a folder"
        raise InputError(f"{option} {path}: cannot write in {existing}, {kind} ({exc.strerror or exc}).") from None
    os.close(fd)
    os.unlink(probe)
