"""Fine-tuning surgery on a GNS: changes to a trained simulator after which it predicts as before
(or, for the stride, from the same weights), so that `runout train --init` starts from the base
model's behaviour: material inputs widened with zero weights (a friction-only base model fine-tuned
with cohesion), a new normalisation absorbed into the weights (fine-tuning on other data or at
another noise), another frame stride (a warm start of a longer step).
"""

from __future__ import annotations

from dataclasses import replace

import torch

from runout.errors import InputError
from runout.gns.simulator import GraphNetworkSimulator, Normalisation, normalisation_buffers


def widen_material_features(simulator: GraphNetworkSimulator, names: tuple[str, ...], source="<model>") -> GraphNetworkSimulator:
    """Add material inputs (e.g. cohesion) with zero weights; predictions do not change."""
    old = simulator.schema.material_features
    if tuple(names[: len(old)]) != tuple(old) or len(names) < len(old):
        raise InputError(
            f"{source}: material features [{', '.join(old)}] cannot be widened to [{', '.join(names)}]; "
            "the new list must start with the old one."
        )
    simulator.network.widen_node_input(len(names) - len(old))
    simulator.schema = simulator.schema.with_material_features(tuple(names))
    return simulator


def renormalise(simulator: GraphNetworkSimulator, stats: Normalisation) -> None:
    """Normalise `simulator` with `stats` from now on, its weights changed so that it predicts
    the same next positions (up to rounding): the node encoder's velocity columns and the
    decoder's last layer absorb the change of the velocity and acceleration scales and means.

    Fine-tuning at another noise needs this: the scales are widened by the training noise,
    and a model that keeps a noisier base's scales learns its targets as a small fraction of
    its output range (noise 0.3 widens the acceleration scale about 20x past the data's)."""
    old = {name: getattr(simulator, name).detach().clone().double() for name in ("vel_mean", "vel_scale", "acc_mean", "acc_scale")}
    new = {name: value.double() for name, value in normalisation_buffers(stats).items()}
    with torch.no_grad():
        # velocity inputs: (v - m) / s = ((v - m') / s') * (s' / s) + (m' - m) / s, per column (history - 1 steps x dim)
        first = simulator.network.node_encoder[0]
        n_vel = (simulator.schema.history - 1) * simulator.schema.dim
        ratio = (new["vel_scale"] / old["vel_scale"]).repeat(simulator.schema.history - 1)
        shift = ((new["vel_mean"] - old["vel_mean"]) / old["vel_scale"]).repeat(simulator.schema.history - 1)
        w = first.weight[:, :n_vel].double()
        first.bias.add_((w @ shift).to(first.bias.dtype))
        first.weight[:, :n_vel] = (w * ratio).to(first.weight.dtype)
        # accelerations: y' a' + m' = y a + m, so y' = y (a / a') + (m - m') / a'
        last = simulator.network.decoder[-1]
        scale = old["acc_scale"] / new["acc_scale"]
        last.weight.copy_((last.weight.double() * scale[:, None]).to(last.weight.dtype))
        last.bias.copy_(((last.bias.double() * old["acc_scale"] + old["acc_mean"] - new["acc_mean"]) / new["acc_scale"]).to(last.bias.dtype))
    simulator.use_statistics(stats)


def restride(simulator: GraphNetworkSimulator, stride: int, stats: Normalisation) -> None:
    """Start a model of another frame stride from `simulator`'s weights (--init with
    --frame-stride K): the schema records K and the normalisation becomes `stats`, those of the
    data's K-frame differences. The network sees inputs and targets normalised as before
    (velocities and accelerations in units of their own spread), so its weights are a warm
    start for the longer step, not a model of it."""
    simulator.schema = replace(simulator.schema, frame_stride=stride)
    simulator.use_statistics(stats)
