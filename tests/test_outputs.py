"""Nothing is overwritten: --out is checked before any work, a folder with another command's
results is refused unless --force, and --force (or the same command again) leaves no file
of the previous run that the new one did not rewrite."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import runout.mpm
from runout.outputs import MARKER, check_folder, claim
from test_cli_exits import DAM, MODEL, one_sentence, run, static_run

NO_WORK = "the command started its work before checking --out"


@pytest.fixture
def mpm_runs(monkeypatch):
    """runout.mpm.simulate replaced by a static run; counts its calls."""
    calls = []

    def fake(scenes, **kwargs):
        calls.append(scenes)
        return static_run(scenes, frames=7)

    monkeypatch.setattr(runout.mpm, "simulate", fake)
    return calls


def test_an_existing_file_as_out_is_refused_before_the_run(tmp_path, capsys, mpm_runs):
    (tmp_path / "taken").write_text("mine")
    code, err = run(["mpm", DAM, "--out", tmp_path / "taken"], capsys)
    assert code == 2 and "is an existing file" in err and one_sentence(err)
    assert not mpm_runs, NO_WORK
    assert (tmp_path / "taken").read_text() == "mine"


def test_an_out_below_a_file_is_refused_before_the_run(tmp_path, capsys, mpm_runs):
    (tmp_path / "file").write_text("")
    code, err = run(["mpm", DAM, "--out", tmp_path / "file" / "sub" / "run"], capsys)
    assert code == 2 and "cannot be created" in err and one_sentence(err) and not mpm_runs


def test_missing_parents_are_created(tmp_path, capsys, mpm_runs):
    assert run(["mpm", DAM, "--out", tmp_path / "a" / "b" / "run", "--no-animate"], capsys)[0] == 0
    assert (tmp_path / "a" / "b" / "run" / "trajectory.npz").is_file()


def test_a_folder_that_cannot_be_written_is_refused_before_the_run(capsys, mpm_runs):
    target = Path("/sys/runout-test-out")
    if check_writable(Path("/sys")):
        pytest.skip("/sys is writable on this machine")
    code, err = run(["mpm", DAM, "--out", target], capsys)
    assert code == 2 and "cannot write" in err and one_sentence(err) and not mpm_runs


def check_writable(folder: Path) -> bool:
    try:
        (folder / ".probe").write_text("")
    except OSError:
        return False
    (folder / ".probe").unlink()
    return True


def test_rollout_over_an_mpm_run_is_refused_then_replaces_it_with_force(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run(["mpm", DAM, "--out", out], capsys)[0] == 0
    before = sorted(p.name for p in out.iterdir())
    assert {"initial.png", "final.png", "animation.gif"} <= set(before)
    argv = ["rollout", "--model", MODEL, DAM, "--out", out, "--frames", "8", "--no-animation"]
    code, err = run(argv, capsys)
    assert code == 2 and "holds the results of `runout mpm`" in err and "--force" in err and one_sentence(err)
    assert sorted(p.name for p in out.iterdir()) == before
    assert run([*argv, "--force"], capsys)[0] == 0
    after = {p.name for p in out.iterdir()}
    assert not after & {"initial.png", "final.png", "animation.gif"}  # nothing left that looks like an MPM run
    assert {"trajectory.npz", "metrics.json", "snapshots.png"} <= after
    assert json.loads((out / MARKER).read_text())["command"] == "rollout"
    assert json.loads((out / "metrics.json").read_text())["frames"] == 8


def test_the_same_command_again_leaves_no_stale_file(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run(["mpm", DAM, "--out", out], capsys)[0] == 0
    assert (out / "animation.gif").is_file()
    assert run(["mpm", DAM, "--out", out, "--no-animate"], capsys)[0] == 0
    assert not (out / "animation.gif").exists() and (out / "trajectory.npz").is_file()


def test_a_folder_runout_did_not_write_is_never_emptied(tmp_path, capsys, mpm_runs):
    (tmp_path / "thesis").mkdir()
    (tmp_path / "thesis" / "chapter1.tex").write_text("precious")
    for extra in ([], ["--force"]):
        code, err = run(["mpm", DAM, "--out", tmp_path / "thesis", *extra], capsys)
        assert code == 2 and "did not write" in err and one_sentence(err)
    assert (tmp_path / "thesis" / "chapter1.tex").read_text() == "precious" and not mpm_runs


def test_a_training_run_of_older_runout_is_recognised(tmp_path, capsys, mpm_runs):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "checkpoint.pt").write_bytes(b"weights")
    code, err = run(["mpm", DAM, "--out", tmp_path / "run"], capsys)
    assert code == 2 and "`runout train`" in err and not mpm_runs


def test_force_on_a_resumable_run_starts_afresh_and_without_it_keeps_everything(tmp_path):
    out = tmp_path / "inv"
    claim(check_folder(out, "invert", ("history.json",), mode="resume"))
    (out / "history.json").write_text("{}")
    claim(check_folder(out, "invert", ("history.json",), mode="resume"))
    assert (out / "history.json").is_file()
    claim(check_folder(out, "invert", ("history.json",), mode="resume", force=True))
    assert not (out / "history.json").exists()


def test_show_writes_exactly_the_file_it_names(tmp_path, capsys):
    code, err = run(["show", DAM, "--out", tmp_path / "pngdir"], capsys)
    assert code == 2 and "must name a picture file" in err and one_sentence(err)
    assert not list(tmp_path.iterdir())
    (tmp_path / "folder").mkdir()
    code, err = run(["show", DAM, "--out", tmp_path / "folder"], capsys)
    assert code == 2 and one_sentence(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder"]


def test_show_reports_the_file_it_wrote(tmp_path, capsys):
    from runout.cli import main

    main(["show", str(DAM), "--out", str(tmp_path / "dam.png")])
    assert capsys.readouterr().out.strip().endswith(f"wrote {tmp_path / 'dam.png'}")
    assert (tmp_path / "dam.png").stat().st_size > 1000


def test_families_checks_its_picture_and_scene_folder_first(tmp_path, capsys):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "notes.txt").write_text("")
    code, err = run(["families", "--family", "d", "--count", "2", "--out", tmp_path / "grid.png",
                     "--scenes", tmp_path / "scenes"], capsys)
    assert code == 2 and "--scenes" in err and not (tmp_path / "grid.png").exists()
