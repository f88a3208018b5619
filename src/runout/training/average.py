"""An exponential moving average of a model's weights, for either learned engine's training
(`runout train --ema DECAY`): one step's weights swing with its batch, the average over about
1 / (1 - DECAY) steps does not. A run that keeps one saves the average as its checkpoint's
`model` (what validation, rollouts and every command use) and the last step's weights as
`train_model` (those the optimiser's state belongs to, from which --resume goes on)."""

from __future__ import annotations

from contextlib import contextmanager

import torch


def last_step_weights(model: torch.nn.Module, state: dict | None) -> dict[str, torch.Tensor] | None:
    """A resumed run that kept a weight average holds it as `model` (now in `model`) and its
    last step's weights as `train_model`: put those in `model`, whose optimiser state they
    are, and return the average's parameters (None when there is none)."""
    if state is None or "train_model" not in state:
        return None
    averaged = {n: p.detach().clone() for n, p in model.named_parameters()}
    model.load_state_dict(state["train_model"])
    return averaged


class WeightAverage:
    """An exponential moving average of a model's parameters (float32), updated after every
    optimiser step: avg <- decay avg + (1 - decay) w. A run that had no average starts it from
    its current weights."""

    def __init__(self, model: torch.nn.Module, decay: float, start: dict[str, torch.Tensor] | None = None):
        self.decay = decay
        source = start if start is not None else dict(model.named_parameters())
        self.values = {n: source[n].detach().float().clone() for n, _ in model.named_parameters()}

    @torch.no_grad()
    def update(self, model: torch.nn.Module) -> None:
        for name, p in model.named_parameters():
            self.values[name].lerp_(p.detach().float(), 1.0 - self.decay)

    def state_dict(self, model: torch.nn.Module) -> dict:
        """model.state_dict() with the averaged parameters in place of the last step's."""
        state = model.state_dict()
        return {k: (self.values[k].to(v.dtype).clone() if k in self.values else v) for k, v in state.items()}

    @torch.no_grad()
    def copy_to(self, model: torch.nn.Module) -> None:
        for name, p in model.named_parameters():
            p.copy_(self.values[name])

    @contextmanager
    def applied(self, model: torch.nn.Module):
        """The model with the averaged weights inside the block, its own after."""
        own = {n: p.detach().clone() for n, p in model.named_parameters()}
        self.copy_to(model)
        try:
            yield model
        finally:
            with torch.no_grad():
                for name, p in model.named_parameters():
                    p.copy_(own[name])
