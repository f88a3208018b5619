"""The one way in for the files a user gives: the path checked for what it is, text decoded
as UTF-8, TOML and JSON parsed within bounds.

Every reader of a scene, spec, metadata or record file comes through here (npz and npy
files through runout.npz, checkpoints through runout.gns.checkpoint, both of which check
their paths here). A path that is missing, a folder where a file is expected (or the
reverse), a dangling symbolic link or one that loops is named for what it is. A parsed file
may nest tables and lists at most MAX_DEPTH deep and hold whole numbers of at most
MAX_WHOLE in size. Each failure is an InputError of one sentence naming the file (exit 2).
"""

from __future__ import annotations

import errno
import json
import os
import sys
import tomllib
from pathlib import Path

from runout.errors import InputError

MAX_DEPTH = 32  # tables and lists inside one another (runout's own files nest at most 6 deep)
MAX_WHOLE = 2**53  # the largest whole number a float holds exactly


def broken_link(path: Path) -> str | None:
    """What is wrong with `path` when it is a symbolic link that leads nowhere, else None."""
    if not path.is_symlink() or path.exists():
        return None
    try:
        path.stat()
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symbolic link that loops back on itself"
    return f"a symbolic link to {os.readlink(path)}, which does not exist"


def file_to_read(path: str | Path, what: str) -> Path:
    """`path` when it is an existing file; else InputError saying what it is instead."""
    path = Path(path)
    if path.is_file():
        return path
    link = broken_link(path)
    if link is not None:
        raise InputError(f"{path}: is {link}; give the {what} itself.")
    if path.is_dir():
        raise InputError(f"{path}: is a folder; give the {what} itself.")
    if path.exists():
        raise InputError(f"{path}: is not a regular file, so it cannot be a {what}.")
    raise InputError(f"{path}: no such {what}.")


def folder_to_read(path: str | Path, what: str) -> Path:
    """`path` when it is an existing folder; else InputError saying what it is instead."""
    path = Path(path)
    if path.is_dir():
        return path
    link = broken_link(path)
    if link is not None:
        raise InputError(f"{path}: is {link}; give the {what} itself.")
    if path.exists():
        raise InputError(f"{path}: is a file; give the {what} itself.")
    raise InputError(f"{path}: no such {what}.")


def read_text(path: str | Path, what: str) -> str:
    """The UTF-8 text of a file."""
    path = file_to_read(path, what)
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InputError(f"{path}: is not UTF-8 text (byte 0x{data[exc.start]:02x} on line {line}); "
                         f"save the {what} as UTF-8.") from None


def read_toml(path: str | Path, what: str) -> dict:
    """The table of a TOML file, bounded (check_plain)."""
    text = read_text(path, what)
    try:
        data = tomllib.loads(text)
    except (ValueError, RecursionError) as exc:  # TOMLDecodeError is a ValueError
        raise InputError(f"{path}: not a valid TOML {what} ({_parse_failure(exc)}).") from None
    check_plain(data, path)
    return data


def read_json(path: str | Path, what: str):
    """The value of a JSON file (NaN and Infinity allowed, for the checks to name), bounded."""
    text = read_text(path, what)
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise InputError(f"{path}: not valid JSON ({_parse_failure(exc)}).") from None
    check_plain(data, path)
    return data


def _parse_failure(exc: Exception) -> str:
    """Why a parser stopped, in words that fit in one sentence."""
    if isinstance(exc, RecursionError):
        return f"it nests tables and lists deeper than the {MAX_DEPTH} levels allowed"
    if "integer string conversion" in str(exc):
        return f"a whole number has more than {sys.get_int_max_str_digits()} digits, beyond the allowed {MAX_WHOLE}"
    return str(exc).rstrip(".").replace(". ", "; ")


def check_plain(data, source) -> None:
    """InputError when `data` nests more than MAX_DEPTH tables and lists, or holds a whole
    number beyond MAX_WHOLE in size; the sentence names the field."""
    stack = [(data, "", 0)]
    while stack:
        value, field, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise InputError(f"{source}: {field} lies {depth} tables and lists deep, more than the {MAX_DEPTH} allowed.")
        if isinstance(value, dict):
            stack += [(v, f"{field}.{k}" if field else str(k), depth + 1) for k, v in value.items()]
        elif isinstance(value, list):
            stack += [(v, f"{field}[{k}]", depth + 1) for k, v in enumerate(value)]
        elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_WHOLE:
            digits = len(str(abs(value)))
            raise InputError(f"{source}: {field or 'the value'} = {str(value)[:12]}… ({digits} digits) is outside the "
                             f"allowed range [-{MAX_WHOLE}, {MAX_WHOLE}].")
