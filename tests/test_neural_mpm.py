"""The neural MPM: its transfers are the MPM's, it learns to move from rest, its gradient is
right, and a training run resumes exactly."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.evaluate.heldout import scene_scores, standing_still
from runout.mpm import simulate
from runout.neural_mpm.checkpoint import read_checkpoint
from runout.neural_mpm.engine import NeuralMPM, NeuralMPMConfig
from runout.neural_mpm.training import BEST, CHECKPOINT, TrainSettings, evaluate, rollout_like, train
from runout.scene import scene_from_dict
from runout.simfiles import statistics, write_metadata, write_simulations
from runout.transfer import GridTransfer, stencil_2d

pytestmark = pytest.mark.usefixtures("one_thread")
REPO = Path(__file__).resolve().parents[1]

# a frictional column (phi 20 deg, c 2 kPa) against the left wall on fixed ground, 8 m cells
# (4 m point spacing), 64 frames: it collapses to the right
COLUMN = {
    "domain": {"width": 96.0, "height": 48.0, "cell_size": 8.0},
    "time": {"frames": 64},
    "materials": {"soil": {"friction_angle": 20.0, "cohesion": 2.0}, "ground": {"model": "elastic"}},
    "regions": [
        {"material": "ground", "polygon": [[0, 0], [96, 0], [96, 4], [0, 4]], "fixed": True},
        {"material": "soil", "polygon": [[0, 4], [24, 4], [24, 40], [0, 40]]},
    ],
}
TINY = NeuralMPMConfig(cell_size=8.0, point_spacing=4.0, history=2, frames_per_call=4, widths=(8, 16),
                       velocity_scale=0.1)


@pytest.fixture(scope="module")
def column():
    return simulate([scene_from_dict(COLUMN, "column")], progress=False)[0]


@pytest.fixture(scope="module")
def dataset(column, tmp_path_factory):
    """A dataset of the one column run as its train and valid splits."""
    folder = tmp_path_factory.mktemp("column_data")
    sim = (column.positions, column.particle_type, column.material_features(2))
    for split in ("train", "valid"):
        write_simulations(folder / f"{split}.npz", [sim])
    meta = statistics([sim], radius=9.2, bounds=column.bounds.tolist(), dt=column.frame_dt)
    write_metadata(folder / "metadata.json", {**meta, "sequence_length": column.n_frames,
                                              "material_features": ["tan_phi", "c_over_100kPa"]})
    return folder


def test_transfers_conserve_mass_and_reproduce_linear_fields():
    g = torch.Generator().manual_seed(1)
    x = torch.rand(500, 2, generator=g, dtype=torch.float64) * torch.tensor([40.0, 24.0]) + 12.0
    scene = (torch.rand(500, generator=g) < 0.5).long()
    t = GridTransfer(x, scene, 8.0, (2, 10, 8))
    mass = t.to_grid(torch.ones(500, 1, dtype=torch.float64))
    assert mass[0].sum().item() == pytest.approx(float((scene == 0).sum()), abs=1e-9)
    assert mass[1].sum().item() == pytest.approx(float((scene == 1).sum()), abs=1e-9)
    i = torch.arange(10, dtype=torch.float64)[:, None] * 8.0
    j = torch.arange(8, dtype=torch.float64)[None, :] * 8.0
    field = (0.3 * i - 1.7 * j + 5.0).expand(2, 1, 10, 8)
    assert torch.allclose(t.to_points(field)[:, 0], 0.3 * x[:, 0] - 1.7 * x[:, 1] + 5.0, atol=1e-10)


def test_the_mpm_and_the_neural_mpm_share_one_stencil():
    from runout.mpm.solver import stencil

    x = torch.rand(50, 2, dtype=torch.float64) * 40.0 + 10.0
    ny = torch.full((50,), 12)
    offsets = torch.tensor([a * 12 + b for a in range(3) for b in range(3)]).expand(50, 9)
    _, w_mpm, fx_mpm = stencil(x, torch.zeros(50, dtype=torch.long), ny, offsets, 8.0)
    _, w, fx = stencil_2d(x / 8.0)
    assert torch.equal(w_mpm, w) and torch.equal(fx_mpm, fx)


def test_an_untrained_engine_stands_still(column):
    engine = NeuralMPM(TINY)
    predicted = rollout_like(engine, column)
    np.testing.assert_array_equal(predicted.positions, np.repeat(column.positions[:1], column.n_frames, 0))


def test_a_tiny_engine_trained_on_one_run_moves_from_rest_and_beats_standing_still(dataset, column, tmp_path):
    settings = TrainSettings(data=str(dataset), out=str(tmp_path / "run"), steps=300, batch_size=4, calls=2,
                             lr=3e-3, lr_final=3e-4, rest_share=0.3, mirror_share=0.0, valid_every=300,
                             valid_count=1, progress=False)
    engine = train(settings, TINY)
    still = scene_scores(standing_still(column), column, 4.0)["position_error_m"]
    result = evaluate(engine, [column])
    travel = float(np.abs(column.positions[-1] - column.positions[0]).max())
    assert travel > 8.0, "the column must collapse for this test to mean anything"
    assert result["displacement_m"] > 0.5 * result["displacement_mpm_m"]  # it moves from rest
    assert result["position_error_m"] < 0.5 * still
    assert (tmp_path / "run" / CHECKPOINT).is_file() and (tmp_path / "run" / BEST).is_file()


def test_swept_input_velocities_carry_a_collapsing_front_the_mean_smooths(column):
    """At the column's fastest frame (8 m cells, its front moving right), the points' own frame
    displacements interpolated back from the grid: the mass-weighted mean per node carries the
    front point short and leaves a residual the sweeps take away, each sweep closer (a field
    that carries every point exists: the MPM moved them with one of that size)."""
    from runout.neural_mpm.engine import FILL_FLOOR, sharpened

    pos = torch.from_numpy(column.positions.astype(np.float64))
    soil = torch.from_numpy(column.soil)
    speed = (pos[1:, soil] - pos[:-1, soil]).norm(dim=-1).mean(1)
    f = int(speed.argmax())
    x, step = pos[f, soil], pos[f + 1, soil] - pos[f, soil]
    t = GridTransfer(x + 16.0, torch.zeros(len(x), dtype=torch.long), 8.0, (1, 20, 12))
    area = torch.full((len(x), 1), 0.25, dtype=torch.float64)
    fill = t.to_grid(area)
    fade = 1.0 / torch.clamp(fill, min=FILL_FLOOR)
    mean = t.to_grid(area * step) * fade
    front = int(x[:, 0].argmax())
    residual = []
    for sweeps in (0, 2, 4, 8, 16):
        carried = t.to_points(sharpened(t, step, area, mean, fade, sweeps))
        residual.append(float((carried - step).norm(dim=-1).mean()))
        if sweeps == 0:
            assert carried[front, 0] < 0.95 * step[front, 0]  # the mean carries the front point short
    assert step[front, 0] > 0.1  # m per frame: the front moves
    assert all(b < a for a, b in zip(residual, residual[1:])), residual
    assert residual[-1] < 0.1 * residual[0], residual  # measured: 0.0285 -> 0.0017 m per frame after 16 sweeps


@pytest.mark.parametrize("sweeps", [0, 2])
def test_the_gradient_through_a_rollout_matches_central_differences(column, sweeps):
    torch.manual_seed(0)
    engine = NeuralMPM(replace(TINY, velocity_sweeps=sweeps)).double()
    for p in engine.parameters():  # a random engine that moves the points
        p.data.normal_(0.0, 0.3)
    x0 = torch.from_numpy(column.positions[0].astype(np.float64))
    ptype = torch.from_numpy(column.particle_type)
    base = torch.from_numpy(column.material_features(2).astype(np.float64))

    def loss(tan_phi: torch.Tensor) -> torch.Tensor:
        material = torch.cat([tan_phi.expand(base.shape[0], 1), base[:, 1:]], 1)
        frames = engine.rollout(x0, ptype, material, column.bounds, 9)
        return frames[-1, :, 0].mean()

    phi = torch.tensor([0.36], dtype=torch.float64, requires_grad=True)
    loss(phi).backward()
    h = 1e-5
    with torch.no_grad():
        numeric = (loss(phi.detach() + h) - loss(phi.detach() - h)) / (2 * h)
    assert abs(numeric.item()) > 1e-4, "the loss must depend on the friction for the check to mean anything"
    assert phi.grad.item() == pytest.approx(numeric.item(), rel=1e-4)


def test_a_resumed_run_continues_exactly(dataset, tmp_path):
    common = dict(data=str(dataset), steps=6, batch_size=2, valid_every=0, save_every=3, progress=False)
    straight = train(TrainSettings(out=str(tmp_path / "a"), **common), TINY)
    train(TrainSettings(out=str(tmp_path / "b"), max_cpu_hours=1e-9, **common), TINY)  # out of time at once
    state = torch.load(tmp_path / "b" / CHECKPOINT, weights_only=True)
    assert state["step"] == 1
    resumed = train(TrainSettings(out=str(tmp_path / "b"), **common), TINY, resume=True)
    for (name, a), (_, b) in zip(straight.state_dict().items(), resumed.state_dict().items()):
        assert torch.equal(a, b), name


def test_a_run_resumed_on_other_datasets_measures_its_ranges_again(dataset, column, tmp_path, capsys):
    wide = _shifted_dataset(column, tmp_path / "wide", 200.0)
    common = dict(batch_size=2, valid_every=0, progress=False, out=str(tmp_path / "run"))
    train(TrainSettings(data=str(dataset), steps=1, **common), TINY)
    assert read_checkpoint(tmp_path / "run" / CHECKPOINT)["data_ranges"]["domain_m"] == [96.0, 48.0]
    capsys.readouterr()
    both = f"{dataset},{wide}"
    train(TrainSettings(data=both, steps=2, **common), TINY, resume=True)
    said = capsys.readouterr().err
    ranges_lines = [line for line in said.splitlines() if "training ranges" in line]  # (beside the schedule's line)
    assert len(ranges_lines) == 1 and "are measured again" in ranges_lines[0] and str(wide) in ranges_lines[0]
    ranges = read_checkpoint(tmp_path / "run" / CHECKPOINT)["data_ranges"]
    assert ranges["domain_m"] == [200.0, 48.0] and "wide" in ranges["source"]
    train(TrainSettings(data=both, steps=3, **common), TINY, resume=True)  # the same list again: the record kept
    assert "measured again" not in capsys.readouterr().err
    assert read_checkpoint(tmp_path / "run" / CHECKPOINT)["data_ranges"] == ranges


def test_a_runs_log_draws_its_loss_and_the_held_out_error_of_each_dataset(dataset, column, tmp_path):
    import json

    from runout.evaluate.heldout_run import curves

    wide = _shifted_dataset(column, tmp_path / "wide", 200.0)
    run = tmp_path / "run"
    train(TrainSettings(data=f"{dataset},{wide}", out=str(run), steps=4, batch_size=2, valid_every=2, valid_count=1,
                        log_every=1, progress=False), TINY)
    drawn = curves(run / "train.log.jsonl", tmp_path / "curves.png")
    rows = [json.loads(line) for line in (run / "train.log.jsonl").read_text().splitlines()]
    valid = [r for r in rows if r["event"] == "valid"]
    assert drawn["last_step"] == 4 and (tmp_path / "curves.png").stat().st_size > 10_000
    assert [(v["data"], v["step"]) for v in drawn["validation"]] == [(str(dataset), 2), (str(wide), 2), (str(dataset), 4),
                                                                     (str(wide), 4)]
    assert [v["position_error_m"] for v in drawn["validation"]] == [r["position_error_m"] for r in valid]
    assert drawn["loss_last_1000_steps"] == pytest.approx(np.mean([r["loss"] for r in rows if r["event"] == "loss"]))


def test_kinematic_points_never_move(column):
    engine = NeuralMPM(TINY)
    for p in engine.parameters():
        p.data.normal_(0.0, 0.3)
    with torch.no_grad():
        frames = engine.rollout(torch.from_numpy(column.positions[0]), torch.from_numpy(column.particle_type),
                                torch.from_numpy(column.material_features(2)), column.bounds, 17)
    fixed = column.particle_type == PARTICLE_TYPE_KINEMATIC
    assert torch.equal(frames[:, fixed], frames[:1, fixed].expand(17, -1, -1))
    lo, hi = torch.tensor(column.bounds[:, 0]), torch.tensor(column.bounds[:, 1])
    assert bool(((frames >= lo.float()) & (frames <= hi.float())).all())
    assert float((frames[-1, ~fixed] - frames[0, ~fixed]).abs().max()) > 0.0


# ----------------------------------------------------------------------------- the model file selects the engine


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    from runout.neural_mpm.checkpoint import save_checkpoint

    torch.manual_seed(0)
    engine = NeuralMPM(TINY)
    for p in engine.parameters():
        p.data.normal_(0.0, 0.1)
    engine.data_ranges = {"friction_angle_deg": [10.0, 40.0], "cohesion_kpa": [0.0, 30.0], "point_spacing_m": 4.0,
                          "source": "a test"}
    return save_checkpoint(tmp_path_factory.mktemp("model") / "neural-mpm.pt", engine)


def test_the_model_file_alone_selects_the_neural_mpm(tiny_checkpoint, tmp_path, capsys):
    from runout.scene import save_scene
    from test_cli_exits import run

    save_scene(scene_from_dict({**COLUMN, "time": {"frames": 17}}, "column"), tmp_path / "column.toml")
    code, err = run(["rollout", "--model", tiny_checkpoint, tmp_path / "column.toml", "--out", tmp_path / "r",
                     "--no-animation", "--stop-speed", "0"], capsys)
    assert code == 0, err
    assert (tmp_path / "r" / "trajectory.npz").is_file()
    meta = __import__("json").loads((tmp_path / "r" / "metadata.json").read_text())
    assert "neural MPM" in meta.get("name", "") or "neural MPM" in str(meta)


def test_a_neural_mpm_rollout_loads_neither_warp_nor_the_mpm(tiny_checkpoint, tmp_path):
    """A learned engine's command pays for no solver it does not run (issue 57 item 6)."""
    import subprocess
    import sys

    from runout.scene import save_scene

    save_scene(scene_from_dict({**COLUMN, "time": {"frames": 9}}, "column"), tmp_path / "column.toml")
    argv = ["rollout", "--model", str(tiny_checkpoint), str(tmp_path / "column.toml"), "--out", str(tmp_path / "r"),
            "--no-animation", "--stop-speed", "0"]
    probe = ("import sys\nfrom runout.cli import main\nmain(sys.argv[1:])\n"
             "print(sorted(m for m in sys.modules if m.split('.')[0] in ('warp', 'meshio') or m.startswith('runout.mpm')))")
    done = subprocess.run([sys.executable, "-c", probe, *argv], capture_output=True, text=True,
                          env={**__import__("os").environ, "PYTHONPATH": str(REPO / "src"), "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"


def test_a_checkpoint_of_one_engine_where_the_other_is_asked_for_is_one_sentence(tiny_checkpoint, tmp_path, capsys):
    from runout.scene import save_scene
    from test_cli_exits import one_sentence, run

    save_scene(scene_from_dict({**COLUMN, "time": {"frames": 17}}, "column"), tmp_path / "column.toml")
    code, err = run(["compare", tmp_path / "column.toml", "--model", tiny_checkpoint, "--engine", "gns",
                     "--out", tmp_path / "c"], capsys)
    assert code == 2 and one_sentence(err) and "holds a neural-mpm model, but --engine gns was asked for" in err
    assert not (tmp_path / "c" / "metrics.json").exists()
    from runout.neural_mpm.checkpoint import read_checkpoint as read_neural_mpm
    from runout.errors import InputError

    gns_file = REPO / "models" / "slope.pt"
    with pytest.raises(InputError, match="holds a gns engine's model where a neural-mpm checkpoint was expected"):
        read_neural_mpm(gns_file)


def test_a_weight_average_is_what_is_scored_and_saved_and_it_resumes_exactly(dataset, column, tmp_path):
    from runout.neural_mpm.checkpoint import load_engine, ship
    from runout.neural_mpm.training import evaluate

    common = dict(data=str(dataset), steps=6, batch_size=2, valid_every=6, valid_count=1, save_every=3, ema=0.5,
                  progress=False)
    straight = train(TrainSettings(out=str(tmp_path / "a"), **common), TINY)
    train(TrainSettings(out=str(tmp_path / "b"), max_cpu_hours=1e-9, **common), TINY)  # out of time at once
    train(TrainSettings(out=str(tmp_path / "b"), **common), TINY, resume=True)
    a, b = (read_checkpoint(tmp_path / run / CHECKPOINT) for run in "ab")
    assert a["step"] == b["step"] == 6
    for key in ("model", "train_model"):
        assert all(torch.equal(a[key][k], b[key][k]) for k in a[key]), key
    assert any(not torch.equal(a["model"][k], a["train_model"][k]) for k in a["model"])  # an average, not the last step
    assert all(torch.equal(v, a["model"][k]) for k, v in straight.state_dict().items())  # the run gives the average
    import json
    valid = [json.loads(line) for line in (tmp_path / "a" / "train.log.jsonl").read_text().splitlines()]
    scored = [row["position_error_m"] for row in valid if row["event"] == "valid"][-1]
    assert scored == pytest.approx(evaluate(load_engine(tmp_path / "a" / CHECKPOINT), [column])["position_error_m"],
                                   rel=1e-6)
    ship(tmp_path / "a" / CHECKPOINT, tmp_path / "shipped.pt", tmp_path / "resume.pt")
    assert "train_model" not in read_checkpoint(tmp_path / "shipped.pt")
    assert "train_model" in read_checkpoint(tmp_path / "resume.pt")


def test_a_shipped_file_holds_the_engine_and_the_resume_file_the_run(dataset, tmp_path):
    from runout.neural_mpm.checkpoint import load_engine, ship

    engine = train(TrainSettings(data=str(dataset), out=str(tmp_path / "run"), steps=2, batch_size=2, valid_every=0,
                                 progress=False), TINY)
    ship(tmp_path / "run" / CHECKPOINT, tmp_path / "shipped.pt", tmp_path / "resume.pt")
    shipped, resume = read_checkpoint(tmp_path / "shipped.pt"), read_checkpoint(tmp_path / "resume.pt")
    assert "optimizer" not in shipped and "optimizer" in resume and shipped["step"] == resume["step"] == 2
    assert shipped["data_ranges"]["friction_angle_deg"] == pytest.approx([20.0, 20.0], abs=1e-4)
    loaded = load_engine(tmp_path / "shipped.pt")
    for (name, a), (_, b) in zip(engine.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name


def _shifted_dataset(column, folder: Path, width: float) -> Path:
    """The column run in a domain `width` m wide (the same points, the right wall moved)."""
    folder.mkdir(parents=True, exist_ok=True)
    sim = (column.positions, column.particle_type, column.material_features(2))
    for split in ("train", "valid"):
        write_simulations(folder / f"{split}.npz", [sim, sim])
    bounds = [[0.0, width], [0.0, float(column.bounds[1][1])]]
    meta = statistics([sim], radius=9.2, bounds=bounds, dt=column.frame_dt)
    write_metadata(folder / "metadata.json", {**meta, "sequence_length": column.n_frames, "cell_size": 8.0,
                                              "material_features": ["tan_phi", "c_over_100kPa"]})
    return folder


def test_two_datasets_train_together_each_batch_from_one_domain(column, tmp_path):
    from runout.neural_mpm.training import training_ranges
    from runout.neural_mpm.windows import WindowSampler

    narrow = _shifted_dataset(column, tmp_path / "narrow", 96.0)
    wide = _shifted_dataset(column, tmp_path / "wide", 200.0)
    sampler = WindowSampler.from_splits([narrow, wide], "train", history=2, material_width=2, shares=[3, 1])
    widths = []
    for n in range(400):
        w = sampler.draw(4, 8, 0.1, 0.5, torch.Generator().manual_seed(n))
        domain = w.points.bounds[:, 0, 1]
        assert torch.all(domain == domain[0])  # one domain per batch: the grid stays its size
        soil = ~w.points.fixed
        # mirrored windows are mirrored in their own domain: every point stays inside it
        assert float(w.x[soil, 0].max()) <= float(domain[0]) and float(w.targets[:, soil, 0].max()) <= float(domain[0])
        widths.append(float(domain[0]))
    wide_share = np.mean(np.array(widths) == 200.0)
    assert 0.19 < wide_share < 0.31  # shares 3 : 1 -> a quarter of the batches (400 draws: +-0.05 is 2.3 sigma)
    only_narrow = WindowSampler.from_splits([narrow, wide], "train", 2, 2, shares=[1, 0])
    assert all(float(only_narrow.draw(4, 8, 0.1, 0.5, torch.Generator().manual_seed(n)).points.bounds[0, 0, 1]) == 96.0
               for n in range(50))
    ranges = training_ranges(f"{narrow},{wide}", TINY)
    assert ranges["domain_m"] == [200.0, 48.0]  # the largest domain, side by side
    assert ranges["friction_angle_deg"] == pytest.approx([20.0, 20.0], abs=1e-4)
    assert "narrow" in ranges["source"] and "wide" in ranges["source"]



def test_the_fronts_term_is_each_scenes_farthest_points_and_pulls_only_them():
    from runout.neural_mpm.training import front_term

    gen = torch.Generator().manual_seed(0)
    scene = torch.tensor([0, 0, 0, 1, 1, 2, 2, 2, 2])
    x = torch.randn(5, 9, generator=gen, dtype=torch.float64, requires_grad=True)
    x_true = torch.randn(5, 9, generator=gen, dtype=torch.float64)
    term = front_term(x, x_true, scene, 3)
    by_hand = 0.0
    for b in range(3):
        mine = scene == b
        by_hand += ((x[:, mine].amax(1) - x_true[:, mine].amax(1)) ** 2).sum() / 15
        by_hand += ((x[:, mine].amin(1) - x_true[:, mine].amin(1)) ** 2).sum() / 15
    assert torch.allclose(term, by_hand)
    term.backward()
    fronts = torch.zeros_like(x, dtype=torch.bool)  # each frame's largest and smallest x of each scene
    for b in range(3):
        cols = torch.nonzero(scene == b).flatten()
        fronts[torch.arange(5), cols[x[:, cols].argmax(1)]] = True
        fronts[torch.arange(5), cols[x[:, cols].argmin(1)]] = True
    assert torch.all(x.grad[~fronts] == 0) and torch.all(x.grad[fronts] != 0)
    assert front_term(x_true, x_true, scene, 3) == 0  # the true fronts cost nothing


def test_the_fronts_weight_adds_to_the_points_loss_and_zero_leaves_it_as_it_was(dataset):
    from runout.neural_mpm.training import front_term, window_loss
    from runout.neural_mpm.windows import WindowSampler

    sampler = WindowSampler.from_split(dataset, "train", history=3, material_width=2)
    torch.manual_seed(0)
    engine = NeuralMPM(NeuralMPMConfig(frames_per_call=4, widths=(8, 16), velocity_scale=0.1))
    window = sampler.draw(2, 8, 0.0, 0.5, torch.Generator().manual_seed(3))
    with torch.no_grad():
        points = window_loss(engine, window, 2)
        assert window_loss(engine, window, 2, 0.0) == points
        pred = engine.advance(window.x, window.velocities, window.points, 2)
        soil = ~window.points.fixed
        cell = engine.config.cell_size
        fronts = front_term(pred[:, soil, 0] / cell, window.targets[:, soil, 0] / cell, window.points.scene[soil], 2)
        assert fronts > 0
        assert torch.allclose(window_loss(engine, window, 2, 0.5), points + 0.5 * fronts)


def test_the_toes_term_is_each_sides_outer_points_against_their_own_truth():
    from runout.neural_mpm.training import toe_term

    gen = torch.Generator().manual_seed(1)
    scene = torch.repeat_interleave(torch.arange(3), torch.tensor([40, 25, 60]))
    x_true = torch.rand(4, 125, generator=gen, dtype=torch.float64) * 100.0
    squared = torch.rand(4, 125, generator=gen, dtype=torch.float64, requires_grad=True)
    term = toe_term(squared, x_true, scene, 3, share=0.1)
    by_hand, toes = 0.0, torch.zeros_like(x_true, dtype=torch.bool)
    for b in range(3):
        cols = torch.nonzero(scene == b).flatten()
        for f in range(4):
            ordered = np.sort(x_true[f, cols].numpy())
            for side in (x_true[f, cols] <= np.quantile(ordered, 0.1), x_true[f, cols] >= np.quantile(ordered, 0.9)):
                by_hand += squared[f, cols][side].sum().item() / (4 * int(side.sum())) / 3
                toes[f, cols[side]] = True
    assert torch.isclose(term, torch.tensor(by_hand, dtype=torch.float64))
    assert 0.15 < toes.float().mean() < 0.3  # about a tenth on each side
    term.backward()
    assert torch.all(squared.grad[~toes] == 0) and torch.all(squared.grad[toes] > 0)
    assert toe_term(torch.zeros_like(x_true), x_true, scene, 3) == 0  # the truth costs nothing


def test_the_toes_weight_adds_to_the_points_loss_and_zero_leaves_it_as_it_was(dataset):
    from runout.neural_mpm.training import toe_term, window_loss
    from runout.neural_mpm.windows import WindowSampler

    sampler = WindowSampler.from_split(dataset, "train", history=3, material_width=2)
    torch.manual_seed(0)
    engine = NeuralMPM(NeuralMPMConfig(frames_per_call=4, widths=(8, 16), velocity_scale=0.1))
    torch.nn.init.normal_(engine.net.out.weight, std=0.05)  # an engine that moves
    window = sampler.draw(2, 8, 0.0, 0.5, torch.Generator().manual_seed(3))
    with torch.no_grad():
        points = window_loss(engine, window, 2)
        assert window_loss(engine, window, 2, 0.0, 0.0) == points
        pred = engine.advance(window.x, window.velocities, window.points, 2)
        soil = ~window.points.fixed
        cell = engine.config.cell_size
        squared = (((pred[:, soil] - window.targets[:, soil]) / cell) ** 2).sum(-1)
        toes = toe_term(squared, window.targets[:, soil, 0], window.points.scene[soil], 2)
        assert toes > 0
        assert torch.allclose(window_loss(engine, window, 2, 0.0, 2.0), points + 2.0 * toes)


def test_motion_weighting_draws_the_moving_scenes_by_their_displacement_and_zero_draws_as_before():
    from runout.neural_mpm.windows import MOTION_FLOOR_M, WindowSampler

    frames, points = 40, 6
    still = np.zeros((frames, points, 2), np.float32)
    moving = np.zeros((frames, points, 2), np.float32)
    moving[:, :, 0] = np.linspace(0.0, 32.0, frames)[:, None]  # every point ends 32 m from its start
    fixed = np.zeros(points, bool)
    material = np.zeros((points, 2), np.float32)
    bounds = [[-100.0, 100.0], [-100.0, 100.0]]

    def sampler():
        return WindowSampler([still, moving], [fixed, fixed], [material, material], bounds, history=2)

    def drawn(s: WindowSampler, seed: int):
        """The windows and the share of them from the moving scene."""
        w = s.draw(64, 4, 0.0, 0.0, torch.Generator().manual_seed(seed))
        return w, float((w.targets[-1, :, 0] - w.x[:, 0]).abs().reshape(64, points).amax(1).gt(0).float().mean())

    plain, _ = drawn(sampler(), 0)
    same, _ = drawn(sampler().weight_by_motion(0.0), 0)
    assert torch.equal(plain.x, same.x) and torch.equal(plain.targets, same.targets)  # 0: as before
    weighted = sampler().weight_by_motion(1.0)
    assert weighted.weights.tolist() == pytest.approx([MOTION_FLOOR_M, 32.0 + MOTION_FLOOR_M])
    moving_share = np.mean([drawn(weighted, seed)[1] for seed in range(20)])
    assert moving_share == pytest.approx(40.0 / 48.0, abs=0.04)  # 32 + 8 against 8
    assert abs(np.mean([drawn(sampler(), seed)[1] for seed in range(20)]) - 0.5) < 0.05


def test_motion_weighting_per_dataset_weights_one_and_draws_the_other_uniformly():
    from runout.neural_mpm.windows import MOTION_FLOOR_M, WindowSampler

    frames, points = 40, 6
    still = np.zeros((frames, points, 2), np.float32)
    moving = np.zeros((frames, points, 2), np.float32)
    moving[:, :, 0] = np.linspace(0.0, 32.0, frames)[:, None]
    fixed = np.zeros(points, bool)
    weighted, plain = np.ones((points, 2), np.float32), np.zeros((points, 2), np.float32)  # the material tells them apart
    bounds = [[-100.0, 100.0], [-100.0, 100.0]]
    sampler = WindowSampler([still, moving, still, moving], [fixed] * 4, [weighted, weighted, plain, plain], bounds,
                            history=2, source=[0, 0, 1, 1], shares=[1.0, 1.0]).weight_by_motion([1.0, 0.0])
    assert sampler.weights.tolist() == pytest.approx([MOTION_FLOOR_M, 32.0 + MOTION_FLOOR_M, 1.0, 1.0])
    shares = {0: [], 1: []}  # dataset -> share of each of its batches' windows from the moving scene
    for seed in range(60):
        w = sampler.draw(32, 4, 0.0, 0.0, torch.Generator().manual_seed(seed))
        moved = (w.targets[-1, :, 0] - w.x[:, 0]).abs().reshape(32, points).amax(1).gt(0).float().mean()
        shares[0 if float(w.points.material[0, 0]) == 1.0 else 1].append(float(moved))
    assert len(shares[0]) > 15 and len(shares[1]) > 15
    assert np.mean(shares[0]) == pytest.approx(40.0 / 48.0, abs=0.04)  # 32 + 8 against 8
    assert np.mean(shares[1]) == pytest.approx(0.5, abs=0.05)  # uniformly
    with pytest.raises(Exception, match="3 exponents for 2 datasets"):
        WindowSampler([still, moving], [fixed] * 2, [plain] * 2, bounds, history=2, source=[0, 1],
                      shares=[1.0, 1.0]).weight_by_motion([1.0, 0.0, 1.0])


def test_velocity_noise_leaves_the_scene_at_rest_and_the_targets_exact(dataset):
    from runout.neural_mpm.windows import WindowSampler

    sampler = WindowSampler.from_split(dataset, "train", history=3, material_width=2)
    for n in range(20):
        plain = sampler.draw(4, 8, 0.3, 0.5, torch.Generator().manual_seed(n))
        noisy = sampler.draw(4, 8, 0.3, 0.5, torch.Generator().manual_seed(n), noise=0.05)
        assert torch.equal(plain.x, noisy.x) and torch.equal(plain.targets, noisy.targets)  # same windows
        assert torch.equal(plain.velocities, sampler.draw(4, 8, 0.3, 0.5, torch.Generator().manual_seed(n)).velocities)
        kick = noisy.velocities - plain.velocities
        soil = ~plain.points.fixed
        assert torch.all(kick[:, ~soil] == 0)  # the ground never moves
        for b in range(4):  # a window's velocities from frame 0 and before (zero in the data) stay exact
            mine = soil & (plain.points.scene == b)
            at_rest = (plain.velocities[:, mine] == 0).all(-1).all(-1)  # history entries before the data's first step
            assert torch.all(kick[at_rest][:, mine] == 0)
    kicks = torch.cat([(sampler.draw(8, 8, 0.0, 0.5, torch.Generator().manual_seed(n), noise=0.05).velocities
                        - sampler.draw(8, 8, 0.0, 0.5, torch.Generator().manual_seed(n)).velocities).flatten()
                       for n in range(20)])
    kicks = kicks[kicks != 0]
    assert float(kicks.std()) == pytest.approx(0.05, rel=0.05) and abs(float(kicks.mean())) < 0.005


# ----------------------------------------------------------------------------- `runout train --engine neural-mpm`
TINY_OPTIONS = ["--engine", "neural-mpm", "--batch-size", "2", "--valid-every", "0", "--log-every", "1", "--no-progress",
                "--cell-size", "8", "--history", "2", "--frames-per-call", "4", "--widths", "8,16"]


def runout_train(argv, capsys) -> tuple[int, str]:
    """Exit code and output (stdout and stderr) of `runout train ARGV` in this process."""
    from runout.cli import main

    try:
        main(["train", *map(str, argv)])
        code = 0
    except SystemExit as done:
        code = done.code
    said = capsys.readouterr()
    return code, said.out + said.err


def logged(out: Path, key: str) -> list:
    import json

    rows = [json.loads(line) for line in (out / "train.log.jsonl").read_text().splitlines()]
    return [row[key] for row in rows if row["event"] == "loss"]


def weights(out: Path) -> dict:
    return torch.load(out / CHECKPOINT, weights_only=True)["model"]


def test_a_run_of_runout_train_stopped_by_ctrl_c_resumes_exactly(dataset, tmp_path, capsys, monkeypatch):
    import os
    import signal

    from runout.neural_mpm.training import Run

    argv = ["--data", dataset, "--steps", 6, *TINY_OPTIONS]
    assert runout_train([*argv, "--out", tmp_path / "whole"], capsys)[0] == 0
    real_step = Run.step

    def step_then_ctrl_c(run, step):
        loss = real_step(run, step)
        if step == 1:
            os.kill(os.getpid(), signal.SIGINT)  # a real Ctrl-C, in the middle of the run
        return loss

    monkeypatch.setattr(Run, "step", step_then_ctrl_c)
    code, said = runout_train([*argv, "--out", tmp_path / "cut"], capsys)
    assert code == 130 and "after step 2" in said and "--resume" in said
    assert torch.load(tmp_path / "cut" / CHECKPOINT, weights_only=True)["step"] == 2
    monkeypatch.setattr(Run, "step", real_step)
    assert runout_train([*argv, "--out", tmp_path / "cut", "--resume"], capsys)[0] == 0
    assert logged(tmp_path / "cut", "loss") == logged(tmp_path / "whole", "loss")  # the redone steps' rows once
    whole, cut = weights(tmp_path / "whole"), weights(tmp_path / "cut")
    assert all(torch.equal(whole[k], cut[k]) for k in whole)


@pytest.mark.parametrize("argv, words", [
    (["--cell-size", "4"], "--cell-size is an option of --engine neural-mpm only; leave it out to train the GNS."),
    (["--max-cpu-hours", "1"], "--max-cpu-hours is an option of --engine neural-mpm only"),
    (["--engine", "neural-mpm", "--pushforward", "2"], "--pushforward is an option of --engine gns only"),
    (["--engine", "neural-mpm", "--device", "cpu"], "--device is an option of --engine gns only"),
    (["--engine", "mpm"], "--engine = mpm must be one of gns, neural-mpm."),
    (["--engine", "neural-mpm", "--calls", "0"], "--calls = 0 is outside the allowed range"),
    (["--engine", "neural-mpm", "--ema", "1.5"], "--ema = 1.5 is outside the allowed range"),
    (["--engine", "neural-mpm", "--noise", "-0.1"], "--noise = -0.1 is outside the allowed range"),
    (["--engine", "neural-mpm", "--widths", "32,x"], "--widths = 32,x must be whole numbers"),
    (["--engine", "neural-mpm", "--velocity-sweeps", "-1"], "--velocity-sweeps = -1 is outside the allowed range"),
    (["--velocity-sweeps", "4"], "--velocity-sweeps is an option of --engine neural-mpm only"),
    (["--engine", "neural-mpm", "--front-loss", "-1"], "--front-loss = -1 is outside the allowed range"),
    (["--front-loss", "0.1"], "--front-loss is an option of --engine neural-mpm only"),
    (["--engine", "neural-mpm", "--toe-loss", "101"], "--toe-loss = 101 is outside the allowed range"),
    (["--toe-loss", "1"], "--toe-loss is an option of --engine neural-mpm only"),
    (["--engine", "neural-mpm", "--motion-weighting", "-1"], "--motion-weighting = -1 is outside the allowed range"),
    (["--engine", "neural-mpm", "--motion-weighting", "1,x"], "--motion-weighting = 1,x must be one number"),
    (["--engine", "neural-mpm", "--motion-weighting", "1,5"], "--motion-weighting = 5 is outside the allowed range"),
])
def test_an_option_of_the_other_engine_or_out_of_range_is_one_sentence(tmp_path, capsys, argv, words):
    from test_cli_exits import one_sentence

    code, said = runout_train(["--data", tmp_path / "missing", "--out", tmp_path / "run", *argv], capsys)
    assert code == 2 and words in said and one_sentence(said), said
    assert not (tmp_path / "run").exists()


def test_motion_weighting_with_more_exponents_than_datasets_is_one_sentence(dataset, tmp_path, capsys):
    from test_cli_exits import one_sentence

    code, said = runout_train(["--engine", "neural-mpm", "--data", dataset, "--out", tmp_path / "run",
                               "--motion-weighting", "1,0"], capsys)
    assert code == 2 and "--motion-weighting = 1,0 gives 2 exponents for 1 dataset;" in said and one_sentence(said), said
    assert not (tmp_path / "run").exists()


def test_a_fixed_decay_goes_on_across_a_resume_with_more_steps(dataset, tmp_path, capsys):
    from runout.neural_mpm.training import learning_rate

    common = ["--data", dataset, *TINY_OPTIONS, "--lr-decay-steps", 6]
    runout_train([*common, "--out", tmp_path / "whole", "--steps", 6], capsys)
    runout_train([*common, "--out", tmp_path / "chunks", "--steps", 3], capsys)
    runout_train([*common, "--out", tmp_path / "chunks", "--steps", 6, "--resume"], capsys)
    expected = [learning_rate(step, TrainSettings(steps=6, lr_decay_steps=6)) for step in range(6)]
    assert logged(tmp_path / "chunks", "lr") == logged(tmp_path / "whole", "lr") == expected
    whole, chunks = weights(tmp_path / "whole"), weights(tmp_path / "chunks")
    assert all(torch.equal(whole[k], chunks[k]) for k in whole)


def test_a_resumed_run_keeps_its_stored_decay_and_an_older_run_its_steps(dataset, tmp_path, capsys):
    from runout.neural_mpm.training import learning_rate

    out = tmp_path / "run"
    runout_train(["--data", dataset, *TINY_OPTIONS, "--out", out, "--steps", 3], capsys)
    code, said = runout_train(["--data", dataset, *TINY_OPTIONS, "--out", out, "--steps", 6, "--resume"], capsys)
    assert code == 0 and "keeps its learning-rate schedule" in said and "over 3 steps" in said
    assert logged(out, "lr")[3:] == [TrainSettings.lr_final] * 3  # the decay over, at lr_final
    older = tmp_path / "older"  # a run from before lr_decay_steps: it decays over the --steps it is given
    runout_train(["--data", dataset, *TINY_OPTIONS, "--out", older, "--steps", 3], capsys)
    state = torch.load(older / CHECKPOINT, weights_only=True)
    del state["train"]["lr_decay_steps"]
    torch.save(state, older / CHECKPOINT)
    runout_train(["--data", dataset, *TINY_OPTIONS, "--out", older, "--steps", 6, "--resume"], capsys)
    assert logged(older, "lr")[3:] == [learning_rate(step, TrainSettings(steps=6)) for step in range(3, 6)]
    assert torch.load(older / CHECKPOINT, weights_only=True)["train"]["lr_decay_steps"] == 6


def test_the_pilot_script_trains_the_run_runout_train_does(dataset, tmp_path, capsys):
    import subprocess
    import sys

    options = ["--data", str(dataset), "--steps", "3", "--batch-size", "2", "--valid-every", "0", "--no-progress",
               "--cell-size", "8", "--history", "2", "--frames-per-call", "4", "--widths", "8,16", "--mirror-share", "0.25"]
    env = {**__import__("os").environ, "PYTHONPATH": str(REPO / "src")}
    subprocess.run([sys.executable, REPO / "scripts" / "neural_mpm_pilot.py", *options, "--out", tmp_path / "pilot"],
                   check=True, env=env, capture_output=True)
    runout_train(["--data", dataset, "--steps", 3, *TINY_OPTIONS, "--mirror", 0.25, "--out", tmp_path / "cli"], capsys)
    pilot, cli = weights(tmp_path / "pilot"), weights(tmp_path / "cli")
    assert all(torch.equal(pilot[k], cli[k]) for k in pilot)


def test_a_run_from_init_starts_from_the_files_engine_with_its_own_sweeps(dataset, tmp_path, capsys):
    """--init: a new run takes the file's config and weights (velocity_sweeps its own), so its
    first loss is the file's engine's on the same window; a resume continues its own checkpoint."""
    import json

    from runout.neural_mpm.checkpoint import load_engine

    runout_train(["--data", dataset, *TINY_OPTIONS, "--out", tmp_path / "base", "--steps", 4], capsys)
    common = ["--data", dataset, "--engine", "neural-mpm", "--batch-size", "2", "--valid-every", "0", "--log-every", "1",
              "--no-progress", "--init", tmp_path / "base" / CHECKPOINT]
    code, said = runout_train([*common, "--out", tmp_path / "swept", "--steps", 1, "--lr", 1e-12, "--velocity-sweeps", 3],
                              capsys)
    assert code == 0, said
    base, swept = load_engine(tmp_path / "base" / CHECKPOINT), load_engine(tmp_path / "swept" / CHECKPOINT)
    assert swept.config == replace(base.config, velocity_sweeps=3)
    assert all(torch.allclose(base.state_dict()[k], v, atol=1e-9) for k, v in swept.state_dict().items())
    rows = [json.loads(line) for line in (tmp_path / "swept" / "train.log.jsonl").read_text().splitlines()]
    assert rows[0]["event"] == "start" and rows[0]["step"] == 0 and rows[0]["settings"]["init"].endswith(CHECKPOINT)
    code, said = runout_train([*common, "--out", tmp_path / "swept", "--steps", 2, "--resume"], capsys)
    assert code == 0 and torch.load(tmp_path / "swept" / CHECKPOINT, weights_only=True)["step"] == 2, said


@pytest.mark.parametrize("extra, words", [
    (["--widths", "8,16"], "--widths comes from the --init file's engine; leave it out"),
    (["--frames-per-call", "4"], "--frames-per-call comes from the --init file's engine"),
])
def test_an_engine_option_beside_init_is_one_sentence(dataset, tmp_path, capsys, extra, words):
    from test_cli_exits import one_sentence

    runout_train(["--data", dataset, *TINY_OPTIONS, "--out", tmp_path / "base", "--steps", 1], capsys)
    code, said = runout_train(["--data", dataset, "--engine", "neural-mpm", "--init", tmp_path / "base" / CHECKPOINT,
                               "--out", tmp_path / "run", *extra], capsys)
    assert code == 2 and words in said and one_sentence(said), said
    assert not (tmp_path / "run").exists()


def test_init_from_a_file_that_is_no_neural_mpm_is_one_sentence(dataset, tmp_path, capsys):
    from test_cli_exits import one_sentence

    torch.save({"engine": "gns", "config": {}, "model": {}}, tmp_path / "gns.pt")
    code, said = runout_train(["--data", dataset, "--engine", "neural-mpm", "--init", tmp_path / "gns.pt",
                               "--out", tmp_path / "run"], capsys)
    assert code == 2 and "gns.pt" in said and one_sentence(said), said
    assert not (tmp_path / "run").exists()


def test_bf16_runs_only_the_unet_in_bfloat16_and_keeps_the_points_float32(column):
    """Inside engine.bfloat16() the U-Net's velocities are bfloat16-rounded (within ~1 % of
    float32's), the positions stay float32, and outside it the engine is float32 again."""
    torch.manual_seed(0)
    engine = NeuralMPM(TINY)
    torch.nn.init.normal_(engine.net.out.weight, std=0.2)  # an engine that moves
    seen = []
    engine.net.register_forward_hook(lambda module, args, out: seen.append(out.dtype))
    start = rollout_like(engine, column).positions
    with engine.bfloat16():
        assert engine.bf16
        halved = rollout_like(engine, column).positions
    assert not engine.bf16 and seen[0] == torch.float32 and seen[-1] == torch.bfloat16
    assert halved.dtype == start.dtype == np.float32
    moved = np.abs(start[8] - start[0]).max()
    assert moved > 0.1, "the engine must move for this test to mean anything"
    assert 0 < np.abs(halved[8] - start[8]).max() < 0.02 * moved


def test_bf16_on_a_cpu_without_native_bfloat16_trains_in_float32_and_says_so(dataset, tmp_path, capsys, monkeypatch):
    from runout.neural_mpm import training as training_module

    common = dict(data=str(dataset), steps=2, batch_size=2, valid_every=0, progress=False, bf16=True)
    monkeypatch.setattr(training_module, "cpu_has_native_bf16", lambda: False)
    plain = train(TrainSettings(out=str(tmp_path / "plain"), **common), TINY)
    assert "no native bfloat16" in capsys.readouterr().err
    assert read_checkpoint(tmp_path / "plain" / CHECKPOINT)["train"]["bf16"] is False
    monkeypatch.setattr(training_module, "cpu_has_native_bf16", lambda: True)
    halved = train(TrainSettings(out=str(tmp_path / "native"), **common), TINY)
    assert "no native bfloat16" not in capsys.readouterr().err
    assert read_checkpoint(tmp_path / "native" / CHECKPOINT)["train"]["bf16"] is True
    assert not halved.bf16  # the engine a run gives is float32, as users run it
    changed = [k for k, v in plain.state_dict().items() if not torch.equal(v, halved.state_dict()[k])]
    assert changed, "bfloat16 steps must differ from float32 steps"


def test_runout_train_passes_bf16_to_the_neural_mpm(dataset, tmp_path, capsys, monkeypatch):
    from runout.neural_mpm import training as training_module

    monkeypatch.setattr(training_module, "cpu_has_native_bf16", lambda: True)
    code, said = runout_train(["--data", dataset, "--steps", 1, *TINY_OPTIONS, "--bf16", "--out", tmp_path / "run"], capsys)
    assert code == 0, said
    assert read_checkpoint(tmp_path / "run" / CHECKPOINT)["train"]["bf16"] is True
