"""The MPM itself as the inverse's forward model, its gradient by reverse-mode AD.

One evaluation is one differentiable MPM run (runout.mpm.differentiable) and one backward
pass, whatever the number of free parameters; mpm-fd needs 2P + 1 runs for the same
gradient. The run is built once from the spec's scene: its substep count and relaxation
length depend on stiffness, density and geometry only, so they stay fixed while L-BFGS-B
moves phi and c.
"""

from __future__ import annotations

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.errors import InputError, RunFailed
from runout.inverse.observation import Observation
from runout.inverse.loss import spec_loss
from runout.inverse.problem import Evaluation, timed_evaluation
from runout.inverse.spec import InverseSpec
from runout.mpm.batch import BACKEND
from runout.mpm.budget import GIB, check_budget, device_memory
from runout.mpm.setup import material_table

STATE_BYTES = 13 * 8  # x, v, C, stress, volume per point in float64: kept at each frame for the backward pass


class MpmAutodiff:
    """Evaluator: physical values [P] -> Evaluation (loss and its exact gradient).

    The MPM and its adjoint run on the fused Warp kernels (runout.mpm.kernels_ad). backend="torch"
    (and with it compile=True) is the torch solver under autograd, the oracle that tests and
    bench/mpm_ad.py compare the kernels with (runout.mpm.differentiable); no command selects it."""

    def __init__(self, spec: InverseSpec, observation: Observation, device: str = "cpu", compile: bool = False,
                 backend: str = BACKEND):
        from runout.mpm.differentiable import DifferentiableMpm

        check_ad_budget(spec, observation, device)
        self.device = torch.device(device)
        self.model = DifferentiableMpm(spec.scene, observation.frames, self.device, torch.float64, compile=compile,
                                       backend=backend)
        f64 = dict(dtype=torch.float64, device=self.device)
        names = spec.scene.material_names
        self.table = torch.tensor(material_table(spec.scene), **f64)  # [M, 2] phi (degrees), c (kPa)
        self.rows = torch.tensor([names.index(p.material) for p in spec.free], device=self.device)
        self.cols = torch.tensor([0 if p.prop == "phi" else 1 for p in spec.free], device=self.device)
        self.data_loss = spec_loss(spec, observation, self.device)

    def __call__(self, values: np.ndarray) -> Evaluation:
        evaluation = timed_evaluation(values, self._loss, self.device)
        if not np.all(np.isfinite(evaluation.gradient)):
            raise RunFailed(f"the MPM gradient at {np.asarray(values).tolist()} is not finite "
                            f"({evaluation.gradient.tolist()}); use --engine mpm-fd.")
        return evaluation

    def predict(self, values: np.ndarray, progress: bool = False) -> np.ndarray:
        """[K, F, N, 2] positions (m) at the observed frames for each row of values [K, P]
        (degrees, kPa): the same MPM run as an evaluation's, forward only."""
        with torch.no_grad():
            runs = [self._positions(torch.tensor(v, dtype=torch.float64, device=self.device))
                    for v in tqdm(np.asarray(values), desc="MPM runs", unit="run", disable=not progress)]
        return torch.stack(runs).cpu().numpy()

    def _loss(self, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        predicted = self._positions(v)
        return self.data_loss(predicted), predicted

    def _positions(self, v: torch.Tensor) -> torch.Tensor:
        table = self.table.index_put((self.rows, self.cols), v)
        return self.model(table[:, 0], table[:, 1])


def check_ad_budget(spec: InverseSpec, observation: Observation, device: str) -> None:
    """The MPM run must fit (runout.mpm.budget), and so must the states kept for the backward pass."""
    frames = observation.frames[-1] + 1
    estimate = check_budget([spec.scene], frames, device, str(spec.source))
    kept = estimate.points * frames * STATE_BYTES
    have = device_memory(device)
    if estimate.device_bytes + kept > have:
        raise InputError(
            f"{spec.source}: the mpm-ad engine keeps {kept / GIB:.3g} GiB of MPM states for the backward pass "
            f"({estimate.points} points, {frames} frames) but this machine has {have / GIB:.3g} GiB; observe an "
            "earlier frame, use a larger cell_size, or use --engine mpm-fd."
        )
