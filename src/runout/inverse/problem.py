"""The differentiable inverse problem: free parameters -> material features -> forward model -> loss.

The forward model is any callable mapping per-point material features [N, k] (tan phi,
c / 100 kPa) to predicted positions [F, N, 2] (m) at the observed frames; the GNS rollout is
one (runout.inverse.forward), a test's toy model another. One call of `evaluate` runs it
forward, then one reverse-mode pass gives the gradient for every free parameter at once.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.errors import InputError
from runout.learned.materials import encode_materials
from runout.inverse.loss import DataLoss
from runout.inverse.memory import PeakMemory
from runout.inverse.spec import FreeParameter

ForwardModel = Callable[[torch.Tensor], torch.Tensor]


@dataclass
class Evaluation:
    values: np.ndarray  # [P] free parameters, physical units (degrees, kPa)
    loss: float  # m^2
    gradient: np.ndarray  # [P] d loss / d value (m^2 per degree or per kPa)
    forward_s: float
    backward_s: float
    peak_memory_bytes: int
    deposit: np.ndarray  # [N, 2] m, predicted positions at the last observed frame


class InverseProblem:
    def __init__(
        self,
        free: tuple[FreeParameter, ...],
        material_names: list[str],
        table: np.ndarray,  # [M, 2] phi (degrees), c (kPa) with fixed values applied
        material_id: np.ndarray,  # [N]
        feature_width: int,  # 1: [tan phi]; 2: [tan phi, c / 100 kPa]
        forward: ForwardModel,
        data_loss: DataLoss,  # predicted positions [F, N, 2] (m) -> m² (runout.inverse.loss)
        device: str = "cpu",
        dtype: torch.dtype = torch.float32,  # of the features handed to the forward model
    ):
        _check_width(free, feature_width)
        self.free = free
        self.forward = forward
        self.feature_width = feature_width
        self.device = torch.device(device)
        self.dtype = dtype
        f64 = dict(dtype=torch.float64, device=self.device)
        self.table = torch.tensor(table, **f64)
        self.rows = torch.tensor([material_names.index(p.material) for p in free], device=self.device)
        self.cols = torch.tensor([0 if p.prop == "phi" else 1 for p in free], device=self.device)
        self.material_id = torch.as_tensor(material_id, device=self.device)
        self.data_loss = data_loss

    def features(self, values: torch.Tensor) -> torch.Tensor:
        """[N, k] per-point features from the free values [P] (degrees, kPa); differentiable."""
        table = self.table.index_put((self.rows, self.cols), values)
        per_material = encode_materials(table[:, 0], table[:, 1])[:, : self.feature_width]
        return per_material[self.material_id].to(self.dtype)

    def loss(self, values: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(loss in m^2, predicted positions [F, N, 2])."""
        predicted = self.forward(self.features(values))
        return self.data_loss(predicted), predicted

    def evaluate(self, values: np.ndarray) -> Evaluation:
        """Loss and its gradient w.r.t. the free values (physical units), with costs."""
        return timed_evaluation(values, self.loss, self.device)

    def predict(self, values: np.ndarray, progress: bool = False) -> np.ndarray:
        """[K, F, N, 2] positions (m) at the observed frames for each row of values [K, P]
        (physical units): forward runs only."""
        with torch.no_grad():
            runs = [self.loss(torch.tensor(v, dtype=torch.float64, device=self.device))[1].to(torch.float64)
                    for v in tqdm(np.asarray(values), desc="rollouts", unit="rollout", disable=not progress)]
        return torch.stack(runs).cpu().numpy()


def timed_evaluation(values: np.ndarray, loss_of, device: torch.device) -> Evaluation:
    """Evaluate loss_of(v) -> (loss, predicted [F, N, 2]) at the free values and backpropagate,
    timing the forward and backward passes and recording the peak memory."""
    v = torch.tensor(np.asarray(values, dtype=np.float64), device=device, requires_grad=True)
    with PeakMemory(device) as memory:
        start = time.perf_counter()
        loss, predicted = loss_of(v)
        _sync(device)
        forward_done = time.perf_counter()
        loss.backward()
        _sync(device)
        backward_done = time.perf_counter()
    return Evaluation(
        values=np.asarray(values, dtype=np.float64),
        loss=float(loss.detach()),
        gradient=v.grad.detach().cpu().numpy(),
        forward_s=forward_done - start,
        backward_s=backward_done - forward_done,
        peak_memory_bytes=memory.peak_bytes,
        deposit=predicted[-1].detach().cpu().numpy().astype(np.float32),
    )


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _check_width(free: tuple[FreeParameter, ...], feature_width: int) -> None:
    if feature_width < 2:
        for p in free:
            if p.prop == "c":
                raise InputError(
                    f"the model reads only tan(phi) (feature width {feature_width}), so it cannot "
                    f"back-calculate {p.name}; use a model fine-tuned with cohesion."
                )
