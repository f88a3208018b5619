"""Reverse mode on the Warp kernels (runout.mpm.kernels_ad): the same run and the same gradients
as torch autograd through the torch solver, and gradients that central differences confirm.

Tolerances, all far above what was measured (2026-12-03): one frame's adjoints of every state
field and strength against torch autograd 1e-9 relative (measured 1e-16 to 2e-15); the gradient
of a deposit loss in phi and c through the K0 start, the relaxation and 12 frames 1e-9 (measured
6e-16 to 3e-15); against central differences 5e-3 as for the torch backend (measured 1e-9 to
6e-5). Torch and Warp round a few operations differently (a last-digit difference in a Mohr
radius was seen), so a point exactly on its yield surface can sit an ulp inside in one and an ulp
outside in the other, where mobilised() meets its cap of 1 and the two one-sided slopes differ:
with an arbitrary stress as input that gave 2e-3 differences in d/dstress, so the one-frame test
starts inside the surface; along a run the stress returned to the surface moves with the
strengths and the two slopes give the same chain (the 6e-16 above)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from runout.inverse import load_inverse_spec, load_observation
from runout.inverse.memory import PeakMemory
from runout.inverse.mpm_ad import MpmAutodiff
from runout.inverse.mpm_fd import MpmFiniteDifference
from runout.mpm import simulate
from runout.mpm.batch import relax_geostatic
from runout.mpm.differentiable import DifferentiableMpm
from runout.mpm.kernels_ad import STATE, Schedule, WarpRun, strength_tensors, warp_substeps
from runout.mpm.mohr_coulomb import MaterialArrays, mobilised
from runout.mpm.setup import build_batch, material_table
from runout.mpm.solver import substep
from runout.scene import save_scene, scene_from_dict
from runout.trajectory import save_trajectory
from _scenes import COLUMN_BESIDE_BLOCK

pytestmark = pytest.mark.usefixtures("one_thread")

FRAMES = [6, 12]
LEAVES = ("sin_phi", "cos_phi", "cohesion", "tension")  # the MaterialArrays fields that follow phi and c


@pytest.fixture(scope="module")
def scene():
    return scene_from_dict(COLUMN_BESIDE_BLOCK, "ad")


def moving_state(scene, frames: int):
    """The batch after its relaxation and `frames` frames (the column collapsing), its stress
    deviator scaled by 0.9 so that no point sits on its yield surface."""
    batch = build_batch([scene], torch.device("cpu"), torch.float64)
    pts = batch.pts
    with torch.no_grad():
        relax_geostatic(batch)
        for _ in range(frames * batch.n_sub):
            substep(pts, batch.grid, batch.dt, batch.flip, batch.damping)
        mean = 0.5 * (pts.stress[:, 0] + pts.stress[:, 1])
        pts.stress = torch.stack((mean + 0.9 * (pts.stress[:, 0] - mean), mean + 0.9 * (pts.stress[:, 1] - mean),
                                  0.9 * pts.stress[:, 2], pts.stress[:, 3]), dim=1)
    assert float(mobilised(pts.stress, pts.mat).max()) < 1.0
    return batch


def frame_gradients(batch, backend: str, hold: bool):
    """Gradients of a fixed random weighting of the state after one frame (or one frame's worth
    of held relaxation substeps, the stress of half the points frozen after 2) with respect to
    the state and the strengths before it."""
    pts, n = batch.pts, batch.n_sub
    state = {name: getattr(pts, name).clone().requires_grad_(True) for name in STATE}
    leaves = {name: getattr(pts.mat, name).clone().requires_grad_(True) for name in LEAVES}
    mat = MaterialArrays(lam=pts.mat.lam, shear=pts.mat.shear, plastic=pts.mat.plastic, **leaves)
    steps = torch.where(torch.arange(len(pts.x)) % 2 == 0, 2, n)
    damping = 0.8 if hold else batch.damping
    if backend == "torch":
        p = replace(pts, mat=mat, **state)
        for k in range(n):
            before = p.stress
            substep(p, batch.grid, batch.dt, batch.flip, damping)
            if hold:
                p.stress, p.x = torch.where((k < steps)[:, None], p.stress, before), state["x"]
        end = [getattr(p, name) for name in STATE]
    else:
        schedule = Schedule(batch.dt, batch.flip, damping, ((0, n),), hold=hold,
                            last_stress_step=steps if hold else None)
        end = warp_substeps(WarpRun(batch, n), schedule, *state.values(), *strength_tensors(mat))[1:]
    gen = torch.Generator().manual_seed(1)
    scale = {"x": 1.0, "v": 1.0, "C": 1.0, "stress": 1e-5, "volume": 1.0}
    loss = sum((torch.randn(e.shape, generator=gen, dtype=e.dtype) * e).sum() * scale[name]
               for name, e in zip(STATE, end))
    loss.backward()
    return {name: t.grad for name, t in {**state, **leaves}.items()}


@pytest.mark.parametrize("hold", [False, True], ids=["frame", "relaxation"])
def test_one_frame_of_adjoints_is_torch_autograd(scene, hold):
    batch = moving_state(scene, 3)
    reference = frame_gradients(batch, "torch", hold)
    fused = frame_gradients(batch, "warp", hold)
    for name, g in reference.items():
        assert float(g.abs().max()) > 0, f"{name}: zero gradient, the test would prove nothing"
        error = float((fused[name] - g).norm() / g.norm())
        assert error < 1e-9, f"d/d{name}: the Warp adjoint differs from torch autograd by {error:.3g} (relative)"


def deposit_loss(model, target):
    def loss(phi, c):
        return (model(phi, c) - target).square().sum(2).mean()
    return loss


def test_warp_run_and_gradient_are_the_torch_ones(scene):
    """DifferentiableMpm(backend="warp") against the torch backend through the K0 start, the
    relaxation and 12 frames: positions to 1e-12 m, gradients to 1e-9 relative (measured 1e-15)."""
    phi0, c0 = (torch.tensor(v) for v in material_table(scene).T)
    torch_model = DifferentiableMpm(scene, FRAMES, backend="torch")
    with torch.no_grad():
        target = torch_model(phi0 + torch.tensor([4.0, -3.0, 0.0]), c0 + torch.tensor([3.0, 5.0, 0.0]))
    results = []
    for model in (torch_model, DifferentiableMpm(scene, FRAMES, backend="warp")):
        phi, c = phi0.clone().requires_grad_(True), c0.clone().requires_grad_(True)
        positions = model(phi, c)
        deposit_loss(lambda *a: positions, target)(phi, c).backward()
        results.append((positions.detach(), torch.cat((phi.grad[:2], c.grad[:2]))))
    (x, grad), (x_warp, grad_warp) = results
    assert float((x[-1] - x[0]).abs().max()) > 0.5  # the column moves
    assert float((x_warp - x).abs().max()) < 1e-12
    assert float(grad.abs().min()) > 1e-6
    error = (grad_warp - grad).abs() / grad.abs()
    assert float(error.max()) < 1e-9, f"relative differences {error.tolist()} (phi column, block; c column, block)"


def test_warp_gradient_equals_central_differences(scene):
    """As tests/test_mpm_differentiable.py for the torch backend: float64, steps of 1e-3."""
    model = DifferentiableMpm(scene, FRAMES, backend="warp")
    phi0, c0 = material_table(scene).T
    with torch.no_grad():
        target = model(torch.tensor(phi0 + [4.0, -3.0, 0.0]), torch.tensor(c0 + [3.0, 5.0, 0.0]))
    loss = deposit_loss(model, target)
    phi, c = torch.tensor(phi0, requires_grad=True), torch.tensor(c0, requires_grad=True)
    loss(phi, c).backward()
    assert phi.grad[2] == 0.0 and c.grad[2] == 0.0  # the fixed ground takes no part
    step = 1e-3
    for which, grad in ((0, phi.grad), (1, c.grad)):
        for k in range(2):
            e = np.zeros((2, 3))
            e[which, k] = step
            with torch.no_grad():
                up = loss(torch.tensor(phi0 + e[0]), torch.tensor(c0 + e[1]))
                down = loss(torch.tensor(phi0 - e[0]), torch.tensor(c0 - e[1]))
            fd = float(up - down) / (2 * step)
            assert abs(fd) > 1e-6
            assert float(grad[k]) == pytest.approx(fd, rel=5e-3)


def test_mpm_ad_on_warp_agrees_with_mpm_fd(scene, tmp_path):
    """The inverse's evaluator (MpmAutodiff, backend="warp") against mpm-fd as in
    tests/test_inverse_mpm_ad.py: c of the column and phi of the block, frames 6 and 12."""
    save_scene(scene, tmp_path / "scene.toml")
    save_trajectory(simulate([scene], progress=False)[0], tmp_path / "target")
    (tmp_path / "spec.toml").write_text(
        'scene = "scene.toml"\n[target]\ntrajectory = "target"\nframes = [6, 12]\n'
        "[parameters.column]\nc = { initial = 12.0, lower = 0.0, upper = 20.0 }\n"
        "[parameters.block]\nphi = { initial = 25.0, lower = 10.0, upper = 35.0 }\n"
    )
    spec = load_inverse_spec(tmp_path / "spec.toml")
    observation = load_observation(spec)
    values = np.array([12.0, 25.0])
    ad = MpmAutodiff(spec, observation, backend="warp")(values)
    fd = MpmFiniteDifference(spec, observation, step=0.008)(values)
    assert ad.loss == pytest.approx(fd.loss, rel=1e-5)
    assert np.all(np.abs(fd.gradient) > 2e-5)
    np.testing.assert_allclose(ad.gradient, fd.gradient, rtol=0.02)


def test_the_warp_backend_refuses_what_it_does_not_do(scene):
    with pytest.raises(ValueError, match="backend"):
        DifferentiableMpm(scene, FRAMES, backend="jax")
    with pytest.raises(ValueError, match="float64"):
        DifferentiableMpm(scene, FRAMES, backend="warp", dtype=torch.float32)


def test_memory_is_the_state_per_frame(scene):
    """The checkpoints (13 float64 numbers per point and frame) are all that grows with the frames
    (runout.inverse.memory's CPU measure: tensors held for the backward pass)."""
    def held(frames: int) -> int:
        model = DifferentiableMpm(scene, [frames], backend="warp")
        phi, c = (torch.tensor(v, requires_grad=True) for v in material_table(scene).T)
        with PeakMemory("cpu") as memory:
            model(phi, c)[-1].square().sum().backward()
        return memory.peak_bytes

    points = len(DifferentiableMpm(scene, [1]).batch.pts.x)
    per_point_frame = (held(9) - held(3)) / (6 * points)
    assert 13 * 8 * 0.9 <= per_point_frame <= 13 * 8 * 1.2


def test_two_threads_give_the_one_thread_gradient_bit_for_bit(scene):
    """With two torch threads the backward pass recomputes the next segment's forward on one
    thread while the adjoints run on the other (two array sets): the same arithmetic in the
    same order, so the same loss and gradients to the last bit."""
    phi0, c0 = (torch.tensor(v) for v in material_table(scene).T)
    with torch.no_grad():
        target = DifferentiableMpm(scene, FRAMES, backend="warp")(phi0 + torch.tensor([4.0, -3.0, 0.0]),
                                                                  c0 + torch.tensor([3.0, 5.0, 0.0]))
    before = torch.get_num_threads()
    grads = {}
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            model = DifferentiableMpm(scene, FRAMES, backend="warp")
            assert len(model.warp.sets) == threads
            phi, c = phi0.clone().requires_grad_(True), c0.clone().requires_grad_(True)
            loss = deposit_loss(model, target)(phi, c)
            loss.backward()
            grads[threads] = (float(loss.detach()), phi.grad.clone(), c.grad.clone())
    finally:
        torch.set_num_threads(before)
    assert float(grads[1][1].abs().max()) > 0
    assert grads[2][0] == grads[1][0]
    assert torch.equal(grads[2][1], grads[1][1]) and torch.equal(grads[2][2], grads[1][2])
