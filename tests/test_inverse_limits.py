"""The inverse analysis refuses what it cannot do and keeps its limits: no strength of an
elastic material, never more evaluations than max_evaluations, --plot-iterations checked
before any work, a corrupt target named in one sentence."""

from __future__ import annotations

import json

import numpy as np
import pytest

from runout.errors import InputError
from runout.inverse import invert, load_inverse_spec
from runout.inverse.figures import draw_deposits, draw_parameters
from runout.inverse.history import HISTORY_JSON, History, Record, RunInfo
from runout.inverse.optimise import deposit_path
from runout.inverse.spec import FreeParameter
from runout.scene import save_scene, scene_from_dict
from test_cli_exits import one_sentence, run
from test_inverse import TOY_SCENE, toy, write_spec  # noqa: F401  (fixtures)

pytestmark = pytest.mark.usefixtures("one_thread")


def test_the_strength_of_an_elastic_material_is_not_optimised(toy, tmp_path):
    scene = json.loads(json.dumps(TOY_SCENE))
    scene["materials"]["right"] = {"model": "elastic"}
    save_scene(scene_from_dict(scene, "elastic"), toy / "elastic.toml")
    path = toy / "elastic_spec.toml"
    path.write_text('scene = "elastic.toml"\n[target]\ntrajectory = "target"\n'
                    '[parameters.right]\nc = { lower = 10.0, upper = 80.0 }\n')
    with pytest.raises(InputError) as err:
        load_inverse_spec(path)
    assert "parameters.right.c cannot be optimised, because material 'right' is elastic" in str(err.value)
    assert "\n" not in str(err.value)


def test_max_evaluations_is_never_exceeded(toy, tmp_path):
    params = ("[parameters.left]\nphi = { initial = 12.0, lower = 5.0, upper = 45.0 }\n"
              "c = { initial = 55.0, lower = 5.0, upper = 60.0 }\n"
              "[optimiser]\nmax_iterations = 20\nmax_evaluations = 3\n[rollout]\nsteps = 8")
    result = invert(write_spec(toy, params, name="three.toml"), tmp_path / "run", model=toy / "model.pt")
    history = json.loads((tmp_path / "run" / HISTORY_JSON).read_text())
    assert len(history["evaluations"]) == 3 == result.best.evaluations
    best = min(e["loss"] for e in history["evaluations"])
    assert result.best.loss == best and "max_evaluations = 3" in result.best.message


def test_plot_iterations_are_checked_before_the_run(toy, tmp_path, capsys):
    spec = write_spec(toy, "[parameters.left]\nc = { lower = 5.0, upper = 60.0 }\n[optimiser]\nmax_iterations = 4",
                      name="plots.toml")
    for bad in ("abc", "0,9"):
        code, err = run(["invert", spec, "--model", toy / "model.pt", "--out", tmp_path / "run",
                         "--plot-iterations", bad], capsys)
        assert code == 2 and "--plot-iterations" in err and "[0, 4]" in err and one_sentence(err)
    assert not (tmp_path / "run").exists()


def test_a_crc_corrupt_target_is_one_sentence(toy, tmp_path, capsys):
    import shutil
    import zipfile

    target = tmp_path / "target"
    shutil.copytree(toy / "target", target)
    npz = target / "trajectory.npz"
    data = bytearray(npz.read_bytes())
    with zipfile.ZipFile(npz) as z:
        info = z.infolist()[0]
    offset = info.header_offset + 30 + len(info.filename) + info.compress_size // 2
    data[offset] ^= 0xFF
    npz.write_bytes(bytes(data))
    spec = tmp_path / "spec.toml"
    spec.write_text(f'scene = "{toy / "toy.toml"}"\n[target]\ntrajectory = "target"\n'
                    '[parameters.left]\nc = { lower = 5.0, upper = 60.0 }\n')
    code, err = run(["invert", spec, "--model", toy / "model.pt", "--out", tmp_path / "run"], capsys)
    assert code == 2 and "trajectory.npz" in err and "corrupt" in err and one_sentence(err)


def test_a_malicious_target_runs_nothing(toy, tmp_path, capsys):
    import shutil

    from test_safe_loading import evil_dict_npz

    target = tmp_path / "target"
    shutil.copytree(toy / "target", target)
    marker = tmp_path / "ran"
    evil_dict_npz(target / "trajectory.npz", marker)
    spec = tmp_path / "spec.toml"
    spec.write_text(f'scene = "{toy / "toy.toml"}"\n[target]\ntrajectory = "target"\n'
                    '[parameters.left]\nc = { lower = 5.0, upper = 60.0 }\n')
    code, err = run(["invert", spec, "--model", toy / "model.pt", "--out", tmp_path / "run"], capsys)
    assert code == 2 and "refused" in err and one_sentence(err) and not marker.exists()


def test_an_answer_kept_from_a_line_search_is_drawn(tmp_path):
    """When the evaluations run out inside a line search, the answer is the lowest loss seen,
    which is no L-BFGS-B iterate (the demo's GNS back-calculation ends so): History.kept names
    it and the figures draw it beside the iterates."""
    free = (FreeParameter("shell", "c", 70.0, 10.0, 100.0),)
    history = History(tmp_path, free, RunInfo("digest", "gns", "model", [0.6]), "cpu", [40.0])
    deposit = np.array([[0.0, 0.0], [10.0, 0.0], [5.0, 5.0]])  # m
    deposit_path(tmp_path, 0).parent.mkdir()
    for k, (c, loss) in enumerate(((15.0, 37.3), (100.0, 68.3), (25.6, 34.1))):
        history.add(Record(k, None, [free[0].normalise(c)], [c], loss, [0.0], [0.0], 1.0, 1.0, 0))
        np.save(deposit_path(tmp_path, k), deposit + c)
    history.mark_iteration(np.array([free[0].normalise(15.0)]), 0)
    history.finish({"values": [25.6], "loss": 34.1})
    assert history.kept is history.records[2]
    draw_parameters(history, tmp_path / "parameters.png")
    draw_deposits(history, deposit, np.zeros(3, int), np.ones(3, bool), [0], tmp_path / "deposit.png")
    assert (tmp_path / "parameters.png").stat().st_size > 0 and (tmp_path / "deposit.png").stat().st_size > 0
    history.finish({"values": [15.0], "loss": 37.3})  # a run that ended on its iterate keeps nothing else
    assert history.kept is None
