"""The MPM as a non-differentiable forward model: gradients by central finite differences.

Each evaluation runs the centre point and, per free parameter, one point below and one
above it (2P + 1 scenes) in ONE batched `runout.mpm.simulate` call. Steps are taken in the
normalised space (a fraction `step` of each parameter's bounds), shortened one-sidedly at a
bound so no scene leaves the box. This is the cost the paper quotes for an MPM-driven
inversion (one run plus finite differences per parameter per iteration).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from runout import checks
from runout.inverse.memory import PeakMemory
from runout.inverse.observation import Observation
from runout.inverse.optimise import central_stencil, spans
from runout.inverse.loss import spec_loss
from runout.inverse.problem import Evaluation
from runout.inverse.spec import InverseSpec
from runout.mpm.batch import BACKEND


MAX_STEP = 0.5  # the largest --fd-step, as a fraction of each parameter's bounds


def check_step(step: float) -> None:
    """InputError unless --fd-step is a finite fraction in (0, MAX_STEP]."""
    checks.number(step, "--fd-step", None, 0.0, MAX_STEP, lo_open=True, note="a fraction of each parameter's bounds")


class MpmFiniteDifference:
    """Evaluator: physical values [P] -> Evaluation (loss and finite-difference gradient).

    backend="torch" (and with it compile=True) is the torch solver, the oracle that tests and
    bench/mpm_ad.py compare the fused kernels with (runout.mpm.simulate); no command selects it."""

    def __init__(self, spec: InverseSpec, observation: Observation, step: float = 0.01,
                 device: str = "cpu", progress: bool = False, compile: bool = False, backend: str = BACKEND):
        check_step(step)
        self.spec = spec
        self.free = spec.free
        self.frames = list(observation.frames)
        self.step = step
        self.device = device
        self.progress = progress
        self.compile = compile  # with backend="torch", the oracle of tests and benchmarks (runout.mpm.simulate)
        self.backend = backend
        self.data_loss = spec_loss(spec, observation)

    def __call__(self, values: np.ndarray) -> Evaluation:
        stencil, spacing = central_stencil(self.free, values, self.step)
        with PeakMemory(self.device) as memory:
            start = time.perf_counter()
            positions = self.predict(stencil, self.progress)
            elapsed = time.perf_counter() - start
        losses = np.array([float(self.data_loss(torch.from_numpy(x))) for x in positions])
        gradient_u = (losses[2::2] - losses[1::2]) / spacing
        return Evaluation(
            values=np.asarray(values, dtype=np.float64),
            loss=float(losses[0]),
            gradient=gradient_u / spans(self.free),
            forward_s=elapsed,
            backward_s=0.0,
            peak_memory_bytes=memory.peak_bytes,
            deposit=positions[0, -1].astype(np.float32),
        )

    def predict(self, values: np.ndarray, progress: bool = False) -> np.ndarray:
        """[K, F, N, 2] positions (m) at the observed frames of the scene at each row of values
        [K, P] (degrees, kPa): one batched MPM run (float32 records)."""
        from runout.mpm import simulate  # the MPM is only needed by this engine

        scenes = [self.spec.scene_at(v) for v in values]
        runs = simulate(scenes, device=self.device, progress=progress, frames=self.frames[-1] + 1,
                        compile=self.compile, backend=self.backend)
        return np.stack([run.positions[self.frames] for run in runs]).astype(np.float64)
