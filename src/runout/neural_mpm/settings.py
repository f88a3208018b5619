"""The settings of a neural-MPM training run, torch-free: TrainSettings, whose defaults are
the pilots' (docs/training.md); runout.train_settings holds their allowed values."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TrainSettings:
    data: str = "data/ft8"  # dataset folder, or several joined by commas (the first one's valid split is the measure)
    data_shares: str | None = None  # the part of the batches from each dataset, e.g. "3,1" (default: by their scenes)
    out: str = "runs/neural-mpm"
    steps: int = 20_000
    batch_size: int = 8
    calls: int = 2  # K: chained calls in the loss
    lr: float = 1e-3
    lr_final: float = 1e-4
    # steps over which the learning rate falls from lr to lr_final, constant after (None: a new run's
    # `steps`; a resumed run's stored value, or for a run older than the setting, its `steps`)
    lr_decay_steps: float | None = None
    rest_share: float = 0.1  # windows that start at frame 0
    mirror_share: float = 0.5
    # std of Gaussian noise on the input velocities of windows that start after frame 0, as a
    # fraction of the data's velocity scale (RMS, m per frame); a window's velocities from
    # before frame 0 (the scene at rest, where every rollout starts) stay exact. 0: none (the
    # anchor's default)
    noise: float = 0.0
    # weight of the fronts' term of the loss: per scene and frame, the squared distance (cells^2)
    # between the predicted and the MPM's largest soil x and between their smallest (the runout
    # fronts the paper measures, L_f), beside the mean over all points; 0: the points alone
    front_loss: float = 0.0
    # weight of the toes' term of the loss: per scene and frame, the mean squared position error
    # (cells^2) of the soil points in each side's outermost 5 % by true x, the two sides summed,
    # beside the mean over all points (each point against its own truth: no pull on the spread);
    # 0: the points alone
    toe_loss: float = 0.0
    # exponent of the draw of each dataset's simulations by motion: weight (D + 8 m)^exponent, D the
    # mean final displacement of its soil (m); 0: uniformly. One number for every dataset, or one
    # per dataset of `data` joined by commas ("1,0,0,1": the first and last weighted, the others drawn
    # uniformly)
    motion_weighting: str | float = 0.0
    # decay per step of the weight average validated and saved as the model (0: the last step's
    # weights, as the pilots of rounds 1-3); the last step's weights are kept for --resume
    ema: float = 0.0
    seed: int = 0
    valid_every: int = 2_000
    valid_count: int = 16
    save_every: int = 250
    log_every: int = 100
    max_hours: float | None = None
    max_cpu_hours: float | None = None
    threads: int = 1
    # autocast the U-Net to bfloat16 in the training steps (the transfers between points and grid,
    # the positions and the validation rollouts stay float32); on a CPU without native bfloat16
    # (AVX512-BF16 or AMX) the run trains in float32 and says so
    bf16: bool = False
    progress: bool = True
    # a neural-MPM checkpoint a new run starts from: its engine (config and weights, the weight
    # average where it kept one) with the run's own velocity_sweeps, a fresh optimiser, step 0
    init: str | None = None

