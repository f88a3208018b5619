"""No file a user made is ever deleted: a command replaces only the names its .runout.json
lists as written by runout, and --force names what it removes before removing it. The
previous run's own results that the new run does not rewrite still go."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import runout.validate
from runout.mpm_run import MPM_FILES
from runout.outputs import MARKER, check_folder, claim
from runout.validate import CaseResult
from test_cli_exits import DAM, one_sentence, run
from test_outputs import mpm_runs  # noqa: F401  (fixture: a static stand-in for the MPM)

MPM = ["mpm", DAM, "--frames", "5"]


def add_user_files(out):
    (out / "notes.txt").write_text("my notes")
    (out / "analysis").mkdir()
    (out / "analysis" / "plot.py").write_text("print('mine')")


def assert_user_files_kept(out):
    assert (out / "notes.txt").read_text() == "my notes"
    assert (out / "analysis" / "plot.py").read_text() == "print('mine')"


def written(out) -> list[str]:
    return json.loads((out / MARKER).read_text())["written"]


def test_a_rerun_keeps_files_the_user_added(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run([*MPM, "--out", out, "--no-animate"], capsys)[0] == 0
    assert written(out) == sorted(MPM_FILES)
    add_user_files(out)
    code, err = run([*MPM, "--out", out, "--no-animate"], capsys)
    assert code == 0 and "removes" not in err
    assert_user_files_kept(out)
    assert (out / "trajectory.npz").is_file() and len(mpm_runs) == 2


def test_a_rerun_still_removes_its_own_results_it_does_not_rewrite(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run([*MPM, "--out", out, "--vtk"], capsys)[0] == 0
    assert (out / "animation.gif").is_file() and (out / "vtk").is_dir()
    add_user_files(out)
    assert run([*MPM, "--out", out, "--no-animate"], capsys)[0] == 0
    assert not (out / "animation.gif").exists() and not (out / "vtk").exists()
    assert_user_files_kept(out)
    assert written(out) == sorted(MPM_FILES)


def test_a_results_folder_holding_the_scene_is_refused_and_keeps_it(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run([*MPM, "--out", out, "--no-animate"], capsys)[0] == 0
    shutil.copyfile(DAM, out / "my_scene.toml")
    code, err = run(["mpm", out / "my_scene.toml", "--frames", "5", "--out", out, "--no-animate", "--force"], capsys)
    assert code == 2 and f"holds the scene {out / 'my_scene.toml'}" in err and one_sentence(err)
    assert (out / "my_scene.toml").read_text() == DAM.read_text() and len(mpm_runs) == 1


def test_a_rerun_keeps_a_nested_run(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run([*MPM, "--out", out, "--no-animate"], capsys)[0] == 0
    assert run([*MPM, "--out", out / "child", "--no-animate"], capsys)[0] == 0
    assert run([*MPM, "--out", out], capsys)[0] == 0
    assert json.loads((out / "child" / MARKER).read_text())["command"] == "mpm"
    assert (out / "child" / "trajectory.npz").is_file()


def test_force_into_another_commands_folder_keeps_user_files_and_names_what_it_removes(tmp_path, capsys, mpm_runs):
    out = tmp_path / "run"
    assert run([*MPM, "--out", out], capsys)[0] == 0
    add_user_files(out)
    argv = ["families", "--family", "d", "--count", "1", "--out", tmp_path / "grid.png", "--scenes", out]
    code, err = run(argv, capsys)
    assert code == 2 and "`runout mpm`" in err and (out / "trajectory.npz").is_file()
    code, err = run([*argv, "--force"], capsys)
    assert code == 0
    [line] = [line for line in err.splitlines() if "--force removes" in line]
    assert all(name in line for name in (*MPM_FILES, "animation.gif")) and "notes.txt" not in line
    assert "analysis" not in line and str(out) in line
    assert sorted(p.name for p in out.iterdir()) == sorted([MARKER, "analysis", "d_000.toml", "notes.txt"])
    assert_user_files_kept(out)
    assert written(out) == ["d_000.toml"]


def test_force_on_a_resumable_run_removes_only_its_own_files(tmp_path, capsys):
    out = tmp_path / "inv"
    claim(check_folder(out, "invert", ("history.json",), mode="resume"))
    (out / "history.json").write_text("{}")
    add_user_files(out)
    claim(check_folder(out, "invert", ("history.json",), mode="resume", force=True))
    assert not (out / "history.json").exists()
    assert "--force removes history.json from" in capsys.readouterr().err
    assert_user_files_kept(out)


def test_a_marker_without_the_list_removes_only_names_that_command_writes(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / MARKER).write_text(json.dumps({"command": "mpm", "runout": "0.1.0"}))
    for name in ("trajectory.npz", "initial.png", "animation.gif", "my_scene.toml"):
        (out / name).write_text("")
    add_user_files(out)
    claim(check_folder(out, "mpm", MPM_FILES))
    assert not (out / "animation.gif").exists()
    assert (out / "my_scene.toml").is_file() and (out / "trajectory.npz").is_file()
    assert_user_files_kept(out)


def test_a_folder_from_before_the_marker_loses_only_names_that_command_writes(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    for name in ("trajectory.npz", "initial.png", "animation.gif"):
        (out / name).write_text("")
    add_user_files(out)
    claim(check_folder(out, "rollout", ("trajectory.npz",), force=True))
    assert sorted(p.name for p in out.iterdir()) == sorted([MARKER, "analysis", "notes.txt", "trajectory.npz"])
    assert "--force removes animation.gif, initial.png from" in capsys.readouterr().err
    assert_user_files_kept(out)


def test_a_marker_cannot_make_runout_remove_files_outside_its_folder(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (tmp_path / "outside.txt").write_text("keep")
    names = ["../outside.txt", str(tmp_path / "outside.txt"), ".", "..", MARKER]
    (out / MARKER).write_text(json.dumps({"command": "mpm", "written": names}))
    claim(check_folder(out, "mpm", MPM_FILES))
    assert (tmp_path / "outside.txt").read_text() == "keep" and (out / MARKER).is_file()


def test_validate_replaces_the_pictures_of_its_previous_checks(tmp_path, capsys, monkeypatch):
    def fake(out, cases=None, report=None, **_):
        results = [CaseResult(case, "largest displacement (m)", 0.5, 0.0, 1.0, "") for case in cases]
        for r in results:
            r.figure = str(out / f"{r.case}.png")
            Path(r.figure).write_text("")
        (out / "results.json").write_text("[]")
        (out / "validation.md").write_text("")
        return results

    monkeypatch.setattr(runout.validate, "CASES", {"cut_a": None, "cut_b": None})
    monkeypatch.setattr(runout.validate, "run_validation", fake)
    out = tmp_path / "val"
    assert run(["validate", "--case", "cut_a", "--out", out], capsys)[0] == 0
    assert written(out) == ["cut_a.png", "results.json", "validation.md"]
    add_user_files(out)
    assert run(["validate", "--case", "cut_b", "--out", out], capsys)[0] == 0
    assert not (out / "cut_a.png").exists() and (out / "cut_b.png").is_file()
    assert_user_files_kept(out)


def test_studies_added_to_one_folder_are_all_recorded(tmp_path):
    out = tmp_path / "eval"
    for study in ("slope", "columns"):
        claim(check_folder(out, "evaluate", (study,), mode="add"))
        (out / study).mkdir()
    assert written(out) == ["columns", "slope"]
