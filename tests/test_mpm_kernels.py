"""The Warp kernels (runout.mpm.kernels) against the torch solver: same physics, frame by frame.

The kernels are what every command runs; the torch solver (runout.mpm.solver) is kept as their
oracle, selected here by run_batch(backend="torch") and by no option of any command. Each scene runs through both backends from the same batch (runout.mpm.setup); the positions of
every point must agree within TOLERANCE cells at every frame, and the scene must really move,
so that agreement is not the agreement of two points at rest."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import warp as wp

from runout.mpm import kernels, simulate
from runout.mpm.batch import relax_geostatic, run_batch
from runout.mpm.mohr_coulomb import MaterialArrays, return_map
from runout.mpm.setup import build_batch
from runout.mpm.solver import DILUTE, LOOSE
from runout.scene import EXAMPLES, load_scene, scene_from_dict, scene_to_dict
from runout.validate import column_scene, cut_scene

pytestmark = pytest.mark.usefixtures("one_thread")

TOLERANCE = 0.02  # cells: "a few hundredths of a cell at every frame" (issue 26)


def both_backends(scenes, frames):
    """(trajectories, batch at the end) of the scenes run as one batch by the torch solver, then
    the same by the Warp kernels."""
    out = []
    for backend in ("torch", "warp"):
        batch = build_batch(scenes, torch.device("cpu"), torch.float64)
        out.append((run_batch(batch, frames, progress=False, backend=backend), batch))
    return out


def assert_same_trajectories(scenes, frames, min_move_cells):
    """Returns both batches at the end (torch, Warp)."""
    (reference, end), (fused, fused_end) = both_backends(scenes, frames)
    for scene, a, b in zip(scenes, reference, fused):
        dx = scene.domain.cell_size
        assert b.info["backend"] == "warp"
        per_frame = np.abs(a.positions - b.positions).max(axis=(1, 2)) / dx  # [T] cells
        moved = np.abs(a.positions[-1] - a.positions[0]).max() / dx
        assert moved >= min_move_cells, f"{scene.name}: moved only {moved:.2f} cells; the test would prove nothing"
        worst = int(per_frame.argmax())
        assert per_frame.max() < TOLERANCE, (
            f"{scene.name}: the Warp kernels differ from the torch solver by {per_frame.max():.3g} cells at frame {worst}")
    return end, fused_end


def assert_same_state(reference, fused):
    """Every state field of two batches agrees to rounding (stress relative to its largest value)."""
    scale = {"x": 1.0, "v": 1.0, "C": 1.0, "volume": 1.0, "stress": float(reference.pts.stress.abs().max())}
    for name, unit in scale.items():
        a, b = getattr(reference.pts, name), getattr(fused.pts, name)
        assert torch.allclose(a, b, rtol=0.0, atol=1e-10 * unit), f"{name} differs by {float((a - b).abs().max()):.3g}"


def test_column_collapse_matches_the_torch_solver():
    assert_same_trajectories([column_scene(20.0, 40.0, 20.0, 0.0, 4.0, 25)], 25, min_move_cells=0.5)


def test_vertical_cut_matches_the_torch_solver():
    """A cut of 16 m with c 10 kPa, phi 20: its crest cracks in tension during the relaxation."""
    assert_same_trajectories([cut_scene(16.0, 20.0, 10.0, 4.0, 25)], 25, min_move_cells=0.3)


def test_four_layer_slope_matches_the_torch_solver():
    """The paper's four-layer slope (examples/four_layer_slope.toml) at 8 m cells: four materials, rough base."""
    data = scene_to_dict(load_scene(EXAMPLES / "four_layer_slope.toml"))
    data["domain"]["cell_size"] = 8.0
    assert_same_trajectories([scene_from_dict(data)], 60, min_move_cells=0.5)


def on_fixed_ground():
    """A column on deep fixed ground (Coulomb contact, stuck nodes) beside an elastic block
    thrown sideways, with a fixed FLIP share and local damping."""
    return scene_from_dict({
        "name": "on_ground",
        "domain": {"width": 80.0, "height": 48.0, "base_friction": 0.3},
        "time": {"frames": 20, "flip": 0.5, "damping": 0.05},
        "materials": {"soil": {"friction_angle": 25.0, "cohesion": 2.0}, "rock": {"model": "elastic"},
                      "ground": {"model": "elastic"}},
        "regions": [
            {"material": "ground", "polygon": [[0, 0], [80, 0], [80, 16], [0, 16]], "fixed": True},
            {"material": "soil", "polygon": [[0, 16], [16, 16], [16, 40], [0, 40]]},
            {"material": "rock", "polygon": [[40, 16], [48, 16], [48, 24], [40, 24]], "velocity": [3.0, 0.0]},
        ],
    })


def test_batched_scenes_on_fixed_ground_with_fixed_flip_and_damping_match():
    """One flat batch of two scenes: the column on fixed ground beside a column on the rigid
    base; each relaxes for its own length."""
    ground = on_fixed_ground()
    column = scene_from_dict({**scene_to_dict(column_scene(12.0, 24.0, 30.0, 0.0, 4.0, 20)), "name": "column",
                              "time": {"frames": 20, "flip": 0.5, "damping": 0.05}})
    batch = build_batch([ground], torch.device("cpu"), torch.float64)
    assert len(batch.grid.stuck) > 0 and math.isfinite(float(batch.grid.constraints[-1].mu[0]))
    assert_same_trajectories([ground, column], 20, min_move_cells=0.3)


def test_torn_block_with_loose_clods_and_dilute_points_matches():
    """Two halves of a block thrown apart at 25 m/s: the tear opens loose clods (no C) and dilute
    points (no stress) within a few frames."""
    torn = scene_from_dict({
        "name": "torn", "domain": {"width": 120.0, "height": 40.0}, "time": {"frames": 12},
        "materials": {"soil": {"friction_angle": 30.0, "cohesion": 5.0}},
        "regions": [
            {"material": "soil", "polygon": [[36, 0], [60, 0], [60, 12], [36, 12]], "velocity": [-25.0, 8.0]},
            {"material": "soil", "polygon": [[60, 0], [84, 0], [84, 12], [60, 12]], "velocity": [25.0, 8.0]},
        ],
    })
    end, fused_end = assert_same_trajectories([torn], 12, min_move_cells=2.0)
    ratio = end.pts.volume / end.pts.rest_volume
    assert int((ratio > DILUTE).sum()) >= 10 and int((ratio > LOOSE).sum()) >= 40
    assert_same_state(end, fused_end)


def test_geostatic_relaxation_matches_state_for_state():
    """A batch of a tall column and a low cut: the cut's relaxation ends first and its stresses
    are held while the column's go on. Every state field agrees to rounding after it."""
    scenes = [column_scene(16.0, 48.0, 25.0, 5.0, 4.0, 3), cut_scene(8.0, 20.0, 10.0, 4.0, 3)]
    reference = build_batch(scenes, torch.device("cpu"), torch.float64)
    fused = build_batch(scenes, torch.device("cpu"), torch.float64)
    steps = relax_geostatic(reference)
    assert relax_geostatic(fused, held=kernels.WarpSubstep(fused.grid, fused.pts).relax) == steps
    assert_same_state(reference, fused)


def test_return_map_kernel_matches_the_torch_return_on_every_branch():
    """Random trial stresses around the yield surface of four materials (phi 0, 20, 40; one
    elastic): shear, tension, corner and apex returns all occur, and agree to rounding."""
    gen = torch.Generator().manual_seed(3)
    n = 4000
    phi = torch.tensor([0.0, 20.0, 40.0, 30.0]).repeat(n // 4).double()
    c = torch.tensor([30e3, 10e3, 2e3, 5e3]).repeat(n // 4).double()
    rad = torch.deg2rad(phi)
    tan = torch.tan(torch.where(rad > 0, rad, torch.ones_like(rad)))
    tension = torch.where(rad > 0, torch.minimum(torch.full_like(c, 1e3), c / tan), torch.full_like(c, 1e3))
    e, nu = 40e6, 0.3
    mat = MaterialArrays(
        lam=torch.full_like(c, e * nu / ((1 + nu) * (1 - 2 * nu))), shear=torch.full_like(c, e / (2 * (1 + nu))),
        sin_phi=torch.sin(rad), cos_phi=torch.cos(rad), cohesion=c, tension=tension,
        plastic=torch.tensor([True, True, True, False]).repeat(n // 4),
    )
    trial = torch.randn(n, 4, generator=gen, dtype=torch.float64) * 60e3 - torch.tensor([20e3, 20e3, 0.0, 20e3])
    expected = return_map(trial, mat)
    got = torch.empty_like(trial)
    wp.launch(_return_map_kernel, dim=n, inputs=[wp.from_torch(trial, dtype=wp.vec4d), kernels.material_constants(mat),
                                                 wp.from_torch(got, dtype=wp.vec4d)], device="cpu")
    moved = (expected - trial).abs().amax(1) > 1.0
    assert moved.float().mean() > 0.3, "too few trial stresses were outside the yield surface"
    assert torch.allclose(got, expected, rtol=1e-12, atol=1e-6), float((got - expected).abs().max())


@wp.kernel
def _return_map_kernel(trial: wp.array(dtype=wp.vec4d), mat: kernels.MaterialConstants,
                       out: wp.array(dtype=wp.vec4d)):
    p = wp.tid()
    out[p] = kernels.return_map(trial[p], mat, p)


def test_the_warp_backend_refuses_float32_and_unknown_backends():
    batch = build_batch([cut_scene(8.0, 20.0, 10.0, 4.0, 3)], torch.device("cpu"), torch.float32)
    with pytest.raises(ValueError, match="float64"):
        run_batch(batch, 3, progress=False, backend="warp")
    with pytest.raises(ValueError, match="backend"):
        run_batch(batch, 3, progress=False, backend="jax")


def test_users_run_the_warp_kernels_and_no_option_selects_the_torch_solver(tmp_path, monkeypatch, capsys):
    import sys

    from runout.cli import main

    scene = cut_scene(8.0, 20.0, 10.0, 4.0, 3)
    assert simulate([scene], progress=False)[0].info["backend"] == "warp"
    batch = build_batch([scene], torch.device("cpu"), torch.float64)
    assert run_batch(batch, 3, progress=False)[0].info["backend"] == "warp"
    monkeypatch.setattr(sys, "argv", ["runout", "mpm", str(EXAMPLES / "column_a1.toml"), "--compile",
                                      "--out", str(tmp_path / "o")])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    assert "--compile" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_scene_groups_split_whole_scenes_with_about_equal_points():
    scene = torch.repeat_interleave(torch.arange(4), torch.tensor([100, 10, 10, 100]))
    offsets = torch.tensor([0, 50, 70, 90])
    assert kernels.scene_groups(scene, offsets, 140, 2) == [(0, 110, 0, 70), (110, 220, 70, 140)]
    assert kernels.scene_groups(scene, offsets, 140, 1) == [(0, 220, 0, 140)]
    assert kernels.scene_groups(scene, offsets, 140, 8) == [(0, 100, 0, 50), (100, 110, 50, 70),
                                                            (110, 120, 70, 90), (120, 220, 90, 140)]


def test_scene_groups_on_threads_give_the_one_thread_trajectories_bit_for_bit():
    """The CPU runs a batch's scenes in groups side by side (one Warp launch runs on one thread);
    each scene's arithmetic is the same, so every stored position is identical."""
    scenes = [scene_from_dict({**scene_to_dict(column_scene(w, 24.0, phi, 0.0, 4.0, 12)), "name": f"c{w:g}"})
              for w, phi in ((12.0, 20.0), (16.0, 30.0), (8.0, 25.0))]
    runs = {}
    before = torch.get_num_threads()
    try:
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            batch = build_batch(scenes, torch.device("cpu"), torch.float64)
            assert len(kernels.WarpSubstep(batch.grid, batch.pts).groups) == threads
            runs[threads] = run_batch(batch, 12, progress=False)
    finally:
        torch.set_num_threads(before)
    assert np.abs(runs[1][0].positions[-1] - runs[1][0].positions[0]).max() > 0.5  # m: the columns collapse
    for threads in (2, 3):
        for a, b in zip(runs[1], runs[threads]):
            assert np.array_equal(a.positions, b.positions), f"{threads} threads changed {a.name}"

