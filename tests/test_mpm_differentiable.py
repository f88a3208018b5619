"""The differentiable MPM (runout.mpm.differentiable): same run as the MPM, exact gradients, bounded memory."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from runout.inverse.memory import PeakMemory
from runout.mpm import simulate
from runout.mpm.differentiable import DifferentiableMpm
from runout.mpm.mohr_coulomb import MaterialArrays, return_map
from runout.mpm.setup import material_table
from runout.scene import scene_from_dict
from _scenes import COLUMN_BESIDE_BLOCK

# a cohesive column beside a lower frictional block on fixed ground: 160 moving points
SCENE = COLUMN_BESIDE_BLOCK
FRAMES = [6, 12]


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def scene():
    return scene_from_dict(SCENE, "ad")


def test_forward_is_the_mpm_run(scene):
    model = DifferentiableMpm(scene, FRAMES)
    phi, c = (torch.tensor(v) for v in material_table(scene).T)
    with torch.no_grad():
        positions = model(phi, c).numpy()
    reference = simulate([scene], progress=False, frames=FRAMES[-1] + 1)[0].positions  # float32
    assert positions.shape == (len(FRAMES), reference.shape[1], 2)
    assert np.abs(positions - reference[FRAMES]).max() < 1e-4  # m: float32 rounding of the record
    assert np.abs(reference[FRAMES[-1]] - reference[0]).max() > 0.5  # and the column does move


def test_ad_gradient_equals_central_differences(scene):
    """d(deposit loss)/d(phi, c) of both soils by reverse-mode AD against central differences (float64)."""
    model = DifferentiableMpm(scene, FRAMES)
    phi0, c0 = material_table(scene).T
    with torch.no_grad():
        target = model(torch.tensor(phi0 + [4.0, -3.0, 0.0]), torch.tensor(c0 + [3.0, 5.0, 0.0]))

    def loss(phi, c):
        return (model(phi, c) - target).square().sum(2).mean()

    phi = torch.tensor(phi0, requires_grad=True)
    c = torch.tensor(c0, requires_grad=True)
    loss(phi, c).backward()
    assert phi.grad[2] == 0.0 and c.grad[2] == 0.0  # the fixed ground takes no part
    for values, grad, step in ((phi0, phi.grad, 1e-3), (c0, c.grad, 1e-3)):
        for k in range(2):
            e = np.zeros(3)
            e[k] = step
            with torch.no_grad():
                up = loss(torch.tensor(phi0 + e if values is phi0 else phi0), torch.tensor(c0 + e if values is c0 else c0))
                down = loss(torch.tensor(phi0 - e if values is phi0 else phi0), torch.tensor(c0 - e if values is c0 else c0))
            fd = float(up - down) / (2 * step)
            assert abs(fd) > 1e-6  # m^2 per degree or kPa: a real sensitivity, not zero against zero
            assert float(grad[k]) == pytest.approx(fd, rel=5e-3)  # measured: 1e-8 (phi), 1e-3 (c)


@pytest.mark.skipif(not os.environ.get("RUNOUT_COMPILE_TESTS"),
                    reason="compiles four graphs, 2-4 minutes on a 2-core CPU: set RUNOUT_COMPILE_TESTS=1")
def test_compiled_is_the_same_run_and_gradient(scene):
    """compile=True (torch.compile of each frame's substeps; 2-4 minutes of compilation on a
    2-core CPU, seconds from torch's disk cache) gives the eager positions and gradient to rounding."""
    frames = [3]
    phi0, c0 = material_table(scene).T
    results = []
    for compile in (False, True):
        model = DifferentiableMpm(scene, frames, compile=compile, backend="torch")
        phi, c = torch.tensor(phi0, requires_grad=True), torch.tensor(c0, requires_grad=True)
        x = model(phi, c)
        (x - x.detach().mean((0, 1))).square().sum().backward()
        results.append((x.detach(), phi.grad, c.grad))
    for eager, compiled in zip(*results):
        assert torch.allclose(compiled, eager, rtol=1e-10, atol=1e-10 * float(eager.abs().max()))
    assert float(results[0][2][:2].abs().min()) > 0  # real sensitivities


def peak_bytes(scene, frames: int, checkpoint: bool) -> int:
    model = DifferentiableMpm(scene, [frames], checkpoint=checkpoint, backend="torch")
    phi, c = (torch.tensor(v, requires_grad=True) for v in material_table(scene).T)
    with PeakMemory("cpu") as memory:
        model(phi, c)[-1].square().sum().backward()
    return memory.peak_bytes


def test_memory_is_the_state_per_frame_not_every_substep(scene):
    """CPU measure: bytes autograd holds for the backward pass (runout.inverse.memory)."""
    plain = {n: peak_bytes(scene, n, False) for n in (3, 6)}
    kept = {n: peak_bytes(scene, n, True) for n in (3, 6)}
    points = len(DifferentiableMpm(scene, [1]).batch.pts.x)
    per_point_frame = (kept[6] - kept[3]) / (3 * points)
    assert per_point_frame <= 13 * 8 * 1.2  # about the state (x, v, C, stress, volume) in float64
    assert kept[6] - kept[3] < (plain[6] - plain[3]) / 10
    assert kept[6] < plain[3] / 5


def test_return_map_under_autograd_is_the_same_and_finite():
    """The autograd-safe radius changes no value, and an isotropic state gets a finite gradient."""
    n = 5
    mat = MaterialArrays(
        lam=torch.full((n,), 23e6, dtype=torch.float64), shear=torch.full((n,), 15e6, dtype=torch.float64),
        sin_phi=torch.full((n,), 0.5, dtype=torch.float64), cos_phi=torch.full((n,), 0.75**0.5, dtype=torch.float64),
        cohesion=torch.full((n,), 1e4, dtype=torch.float64), tension=torch.full((n,), 5e3, dtype=torch.float64),
        plastic=torch.ones(n, dtype=torch.bool),
    )
    stress = torch.tensor([
        [0.0, 0.0, 0.0, 0.0], [-1e5, -1e5, 0.0, -1e5], [-5e4, -2e5, 3e4, -8e4], [2e4, -1e4, 0.0, 0.0], [1e4, 1e4, 0.0, 1e4],
    ], dtype=torch.float64)
    plain = return_map(stress, mat)
    tracked = stress.clone().requires_grad_(True)
    returned = return_map(tracked, mat)
    assert torch.equal(returned.detach(), plain)
    returned.sum().backward()
    assert torch.isfinite(tracked.grad).all()
