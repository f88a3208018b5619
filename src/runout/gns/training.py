"""What a GNS training step minimises, as in DeepMind's learned_simulator: random-walk noise on
the input positions, the target acceleration corrected for it, the loss over the points that
move, and the pushforward window (the model's own rollout, without gradient, that a step may
start from). runout.train runs the loop around them.

    constraints = Constraints.of(particle_type, bounds, positions, graph, simulator.point_spacing)
    window = pushforward(simulator, window, n, particle_type, material, constraints)          # n >= 0 steps
    noisy, target = training_inputs(simulator, window, next_position, constraints, generator)
    loss = masked_loss(simulator(noisy, particle_type, material, constraints.bounds), target, constraints)
"""

from __future__ import annotations

import torch

from runout.gns.features import Constraints
from runout.gns.simulator import GraphNetworkSimulator


@torch.no_grad()
def pushforward(simulator: GraphNetworkSimulator, window, steps: int, particle_type, material, constraints: Constraints,
                graph=None) -> torch.Tensor:
    """The window [N, history, 2] (m) after `steps` rollout steps of the model from `window`,
    without gradient: each step appends its prediction, constrained as in GraphNetworkSimulator.step, and
    drops the oldest position, as runout.gns.rollout does (Brandstetter et al. 2022's
    pushforward: training inputs that carry the model's own errors)."""
    for _ in range(steps):
        nxt = simulator.step(window, particle_type, material, constraints, graph)
        window = torch.cat([window[:, 1:], nxt[:, None]], dim=1)
    return window


def training_inputs(simulator: GraphNetworkSimulator, window, next_position, constraints: Constraints, generator: torch.Generator,
                    held: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """(noisy window [N, history, 2] m, normalised noise-corrected target acceleration
    [N, 2]): random-walk noise of std stats.noise_std on the moving points' inputs, none
    on the `held` [N] leading positions that are the scene at rest (exact in a rollout)."""
    noise = random_walk_noise(window, simulator.stats.noise_std, constraints.movable, generator, held)
    noisy = window + noise
    return noisy, simulator.normalise_acceleration(corrected_target(noisy, next_position, noise))


def masked_loss(predicted: torch.Tensor, target: torch.Tensor, constraints: Constraints,
                weights: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared error of the normalised accelerations over the movable (not kinematic)
    points, each weighted by `weights` [N] when given (a weighted mean)."""
    error = (predicted.float() - target).square().sum(dim=1)
    w = constraints.movable.to(error.dtype) if weights is None else constraints.movable * weights
    return (error * w).sum() / w.sum().clamp(min=1e-12)


def random_walk_noise(window: torch.Tensor, noise_std: float, movable: torch.Tensor, generator: torch.Generator,
                      held: torch.Tensor | None = None):
    """Position noise [N, history, 2] (m) whose velocities are a random walk: each of the
    history - 1 velocity increments ~ N(0, noise_std^2 / (history - 1)), so the last input
    velocity carries noise of std noise_std; the first position is untouched and kinematic
    points get none. With held [N], a point's first held positions (the scene at rest, which a
    rollout starts from exactly) get none either: the walk starts at the last of them, as a
    rollout's error starts growing only with its first step."""
    n, history, dim = window.shape
    step = torch.randn((n, history - 1, dim), generator=generator, device=window.device, dtype=window.dtype)
    if held is not None:  # increment i moves position i + 1: none while that position is still held
        step = step * (torch.arange(1, history, device=window.device)[None, :, None] >= held[:, None, None])
    velocity_noise = torch.cumsum(step * (noise_std / (history - 1) ** 0.5), dim=1)
    position_noise = torch.cat([torch.zeros_like(window[:, :1]), torch.cumsum(velocity_noise, dim=1)], dim=1)
    return position_noise * movable[:, None, None]


def corrected_target(noisy_window: torch.Tensor, next_position: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
    """Target acceleration (m / step^2) for noisy inputs. The next position is moved by the
    same noise as the current one (public recipe), so the update with this acceleration
    gives x_t + noise_t + (x_{t+1} - x_t): the true next velocity from the noisy position."""
    target = next_position + noise[:, -1]
    return (target - noisy_window[:, -1]) - (noisy_window[:, -1] - noisy_window[:, -2])
