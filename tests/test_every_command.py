"""Every command refuses a small table of bad values with exit 2 and one sentence, no
traceback. The commands are read from the Typer app, so a command added later is walked too
(a new required value that is not a file needs an entry in REQUIRED_VALUES).

Each command is called with its input files missing, so it can do no work: a bad option
value must be refused before any file is read, and a missing or unreadable input file is
itself a bad value."""

from __future__ import annotations

import typing
from pathlib import Path

import pytest
import typer

from runout.cli import app
from test_cli_exits import one_sentence, run

OUTPUTS = {"out", "cache", "scenes", "report", "doc"}  # path options a command writes, not reads
REQUIRED_VALUES = {"stage": "base", "count": "10", "family": "a"}  # valid values of required non-file parameters


def commands() -> list[tuple[tuple[str, ...], object]]:
    """(words, click command) of every command and subcommand of the app."""
    found = []

    def walk(command, words):
        if hasattr(command, "commands"):
            for name, sub in command.commands.items():
                walk(sub, (*words, name))
        else:
            found.append((words, command))

    walk(typer.main.get_command(app), ())
    return found


def kind(param) -> type:
    """The value type of a parameter (the element type of a list)."""
    annotation = param.type_descriptor.annotation
    return typing.get_args(annotation)[0] if typing.get_origin(annotation) is list else annotation


def is_input(param) -> bool:
    return kind(param) is Path and param.name not in OUTPUTS


COMMANDS = commands()
IDS = [" ".join(words) for words, _ in COMMANDS]
# (words, command, option) for every option of a kind, named "command --option"
DEVICES = [(w, c, p) for w, c in COMMANDS for p in c.params if p.name == "device"]
NUMBERS = [(w, c, p) for w, c in COMMANDS for p in c.params if kind(p) is float]
INPUTS = [(w, c, p) for w, c in COMMANDS for p in c.params if is_input(p)]


def ids(cases) -> list[str]:
    return [" ".join((*words, p.opts[0])) for words, _, p in cases]


def argv(words, command, tmp: Path, **values) -> list[str]:
    """The command with every input file missing (or as `values` give it), outputs in tmp and
    the required values filled in."""
    args = list(words)
    for p in command.params:
        if p.name in values:
            value = values[p.name]
        elif is_input(p):
            value = tmp / "missing" / p.name
        elif kind(p) is Path and p.required:
            value = tmp / p.name
        elif p.required:
            assert p.name in REQUIRED_VALUES, f"add a valid value of `{' '.join(words)}`'s {p.name} to REQUIRED_VALUES"
            value = REQUIRED_VALUES[p.name]
        else:
            continue
        args += [str(value)] if p.param_type_name == "argument" else [p.opts[0], str(value)]
    return args


def refused(code: int, err: str, *words: str) -> bool:
    return code == 2 and one_sentence(err) and any(w in err for w in words)


def names(param) -> tuple[str, ...]:
    """How a sentence may name an option: --cell-size or cell_size."""
    return param.opts[0], param.name


def test_the_walk_finds_every_command():
    assert {"mpm", "train", "rollout", "invert", "generate", "inspect", "evaluate columns"} <= set(IDS)
    assert {"rollout", "train", "mpm"} <= {" ".join(w) for w, _, _ in DEVICES}


@pytest.mark.parametrize("words, command", COMMANDS, ids=IDS)
def test_an_unknown_option_is_refused(tmp_path, capsys, words, command):
    code, err = run([*argv(words, command, tmp_path), "--no-such-option", "1"], capsys)
    assert refused(code, err, "--no-such-option"), err


@pytest.mark.parametrize("words, command, option", DEVICES, ids=ids(DEVICES))
@pytest.mark.parametrize("device", ["tpu", "cuda:99", "cuda:x"])
def test_a_device_this_machine_cannot_serve_is_refused(tmp_path, capsys, words, command, option, device):
    code, err = run(argv(words, command, tmp_path, device=device), capsys)
    assert refused(code, err, device), err


@pytest.mark.parametrize("words, command, option", NUMBERS, ids=ids(NUMBERS))
@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_a_number_that_is_not_finite_is_refused(tmp_path, capsys, words, command, option, value):
    code, err = run(argv(words, command, tmp_path, **{option.name: value}), capsys)
    assert refused(code, err, *names(option)), err


@pytest.mark.parametrize("words, command, option", INPUTS, ids=ids(INPUTS))
def test_a_missing_or_unreadable_input_file_is_refused(tmp_path, capsys, words, command, option):
    code, err = run(argv(words, command, tmp_path), capsys)
    assert refused(code, err, "missing"), err
    junk = tmp_path / "junk.json"
    junk.write_text("[1, 2]")
    code, err = run(argv(words, command, tmp_path, **{option.name: junk}), capsys)
    assert code == 2 and one_sentence(err), err
