"""The checks of a GNS checkpoint's every entry, one sentence each (InputError, exit 2), so that a
damaged or foreign file stops before any of it is used: the schema, statistics, radius, layer
sizes and training ranges in range (runout.checks), the weights finite, and the training state
stored beside them (step, rng, optimizer, train settings) when present. `check_resumable`
adds what `runout train --resume` needs (every key, Adam moments of the model's shapes) and
`check_schema` compares a model's node-feature schema with a dataset's.
"""

from __future__ import annotations

import math
from dataclasses import fields

import torch

from runout import checks
from runout.contract import MAX_RADIUS
from runout.errors import InputError
from runout.gns.schema import MAX_STEPS, FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.scene.limits import MAX_DOMAIN


def check_contents(ckpt: dict, path) -> None:
    """Raise InputError naming the first malformed entry of schema, stats, radius, network,
    data ranges, the model weights (finite) and the training state stored beside them."""
    for key in ("schema", "stats", "network"):
        _check_is_table(ckpt[key], key, path)
    checks.number(ckpt["radius"], "radius", path, 0.0, MAX_RADIUS, " m", lo_open=True)
    _check_table(ckpt["network"], {f.name for f in fields(NetworkConfig)}, "network", path)
    problem = NetworkConfig.problem(ckpt["network"])
    if problem:
        raise InputError(f"{path}: network.{problem}.")
    _check_table(ckpt["schema"], {f.name for f in fields(FeatureSchema)}, "schema", path)
    problem = FeatureSchema.problem(ckpt["schema"])
    if problem:
        raise InputError(f"{path}: schema.{problem}.")
    _check_table(ckpt["stats"], {f.name for f in fields(Normalisation)}, "stats", path, require=True)
    problem = Normalisation.problem(ckpt["stats"])
    if problem:
        raise InputError(f"{path}: stats.{problem}.")
    if ckpt.get("data_ranges") is not None:
        _check_data_ranges(ckpt["data_ranges"], path)
    _check_weights(ckpt["model"], path)
    if "train_model" in ckpt:  # a run that saves a weight average (--ema) keeps its last step's weights here
        _check_weights(ckpt["train_model"], path, "train_model")
    _check_training_state(ckpt, path)


# data_ranges (runout.gns.training_range): key -> (lowest, highest, unit, whole numbers, rising) of each pair
_RANGE_PAIRS = {
    "friction_angle_deg": (0.0, 90.0, " degrees", False, True), "cohesion_kpa": (0.0, math.inf, " kPa", False, True),
    "domain_m": (0.0, MAX_DOMAIN, " m", False, False), "materials_per_scene": (0, 10_000, "", True, True),
}


def _check_data_ranges(ranges, path) -> None:
    """What the model was trained on: [lo, hi] pairs in range (or none), a positive point
    spacing and a text source, so the range warnings can compare against them."""
    _check_is_table(ranges, "data_ranges", path)
    _check_table(ranges, {*_RANGE_PAIRS, "point_spacing_m", "source"}, "data_ranges", path)
    for key, (lo, hi, unit, whole, rising) in _RANGE_PAIRS.items():
        pair = ranges.get(key)
        if pair is None:
            continue
        field = f"data_ranges.{key}"
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise InputError(f"{path}: {field} = {checks.show(pair)} must be a pair [lowest, highest]{unit}.")
        low, high = (checks.number(v, f"{field}[{k}]", path, lo, hi, unit, whole=whole) for k, v in enumerate(pair))
        if rising and low > high:
            raise InputError(f"{path}: {field} = {checks.show(list(pair))} must rise from the lowest to the highest value.")
    if ranges.get("point_spacing_m") is not None:
        checks.number(ranges["point_spacing_m"], "data_ranges.point_spacing_m", path, 0.0, MAX_RADIUS, " m", lo_open=True)
    if not isinstance(ranges.get("source", ""), str):
        raise InputError(f"{path}: data_ranges.source = {checks.show(ranges['source'])} must be text.")


def _check_is_table(value, key: str, path) -> None:
    if not isinstance(value, dict):
        raise InputError(f"{path}: the checkpoint's '{key}' is a {type(value).__name__}; expected a table.")


def _check_weights(model, path, entry: str = "model") -> None:
    """Finite model weights: a NaN or infinite one is a damaged file or a diverged training run."""
    _check_is_table(model, entry, path)
    for key, value in model.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and not torch.isfinite(value).all():
            raise InputError(f"{path}: the {entry} weight '{key}' holds NaN or infinite values where only finite "
                             "numbers are allowed, so the file is damaged or its training diverged.")


def _check_training_state(ckpt: dict, path) -> None:
    """step, best_valid, rng, optimizer and train settings, each when present."""
    if "step" in ckpt:
        checks.number(ckpt["step"], "step", path, 0, MAX_STEPS, whole=True)
    if "best_valid" in ckpt and ckpt["best_valid"] != math.inf:
        checks.number(ckpt["best_valid"], "best_valid", path, 0.0, note="a position MSE in m², or inf")
    if "rng" in ckpt:
        _check_rng(ckpt["rng"], path)
    if "optimizer" in ckpt:
        _check_optimizer(ckpt["optimizer"], path)
    if "train" in ckpt:
        _check_is_table(ckpt["train"], "train", path)
        offset = ckpt["train"].get("lr_step_offset", 0)
        checks.number(offset, "train.lr_step_offset", path, 0, MAX_STEPS, whole=True)


def _check_rng(rng, path) -> None:
    _check_is_table(rng, "rng", path)
    if "seed" in rng:
        checks.number(rng["seed"], "rng.seed", path, whole=True)
    state, size = rng.get("torch"), torch.get_rng_state().numel()
    if not isinstance(state, torch.Tensor) or state.dtype != torch.uint8 or tuple(state.shape) != (size,):
        raise InputError(f"{path}: rng.torch is {_describe(state)}; expected the state of torch's CPU generator, "
                         f"a uint8 tensor of shape ({size},).")


def _check_optimizer(optimizer, path) -> None:
    """Adam's state_dict: param_groups with finite settings and whole parameter indices, and
    finite moment tensors per parameter."""
    _check_is_table(optimizer, "optimizer", path)
    state, groups = optimizer.get("state"), optimizer.get("param_groups")
    if not isinstance(state, dict) or not isinstance(groups, list) or not all(isinstance(g, dict) for g in groups):
        raise InputError(f"{path}: optimizer holds {_describe(state)} as 'state' and {_describe(groups)} as "
                         "'param_groups'; expected Adam's state_dict, a table and a list of tables.")
    for k, group in enumerate(groups):
        where = f"optimizer.param_groups[{k}]"
        checks.number(group.get("lr"), f"{where}.lr", path, 0.0, 1.0)
        checks.number(group.get("eps"), f"{where}.eps", path, 0.0, 1.0, lo_open=True)
        checks.number(group.get("weight_decay", 0.0), f"{where}.weight_decay", path, 0.0, 1.0)
        for j, beta in enumerate(checks.numbers(group.get("betas"), f"{where}.betas", path, 2, 0.0)):
            checks.number(beta, f"{where}.betas[{j}]", path, 0.0, 1.0, note="below 1")
        params = group.get("params")
        if not isinstance(params, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in params):
            raise InputError(f"{path}: {where}.params = {checks.show(params)} must be a list of parameter indices.")
    for i, entry in state.items():
        _check_is_table(entry, f"optimizer.state[{i}]", path)
        for key, value in entry.items():
            where = f"optimizer.state[{i}].{key}"
            if not isinstance(value, torch.Tensor):
                checks.number(value, where, path)
            elif value.is_floating_point() and not torch.isfinite(value).all():
                raise InputError(f"{path}: {where} holds NaN or infinite values where only finite numbers are allowed.")


def _describe(value) -> str:
    if isinstance(value, torch.Tensor):
        return f"a {str(value.dtype).removeprefix('torch.')} tensor of shape {tuple(value.shape)}"
    return "nothing" if value is None else f"a {type(value).__name__}"


def check_resumable(ckpt: dict, simulator: GraphNetworkSimulator, path, settings: type) -> None:
    """InputError unless `ckpt` holds a training state that continues `simulator`: step, rng,
    optimizer (Adam, one moment per parameter of the model's shape) and train settings whose
    fields are of the types the dataclass `settings` (runout.train.TrainConfig) declares."""
    for key in ("step", "rng", "optimizer", "train"):
        if key not in ckpt:
            raise InputError(f"{path}: the checkpoint lacks '{key}', so training cannot resume from it "
                             "(a weights-only file such as best.pt starts a new run with --init).")
    _check_setting_types(ckpt["train"], settings, path)
    if "train_model" in ckpt:  # --ema: the last step's weights, which the optimiser state belongs to
        own, last = simulator.state_dict(), ckpt["train_model"]
        wrong = [k for k in own if not isinstance(last.get(k), torch.Tensor) or last[k].shape != own[k].shape]
        if wrong or len(last) != len(own):
            name = wrong[0] if wrong else next(k for k in last if k not in own)
            raise InputError(f"{path}: train_model['{name}'] is {_describe(last.get(name))}; the model's weight of "
                             "that name has another shape or none, so the last step's weights are not this model's.")
    params = list(simulator.parameters())
    indices = [i for group in ckpt["optimizer"]["param_groups"] for i in group["params"]]
    if sorted(indices) != list(range(len(params))):
        raise InputError(f"{path}: optimizer.param_groups name {len(indices)} parameters but the model has "
                         f"{len(params)}, so the optimiser state is not this model's.")
    for i, entry in ckpt["optimizer"]["state"].items():
        for key in ("exp_avg", "exp_avg_sq"):
            moment = entry.get(key)
            if i not in range(len(params)) or not isinstance(moment, torch.Tensor) or moment.shape != params[i].shape:
                shape = tuple(params[i].shape) if i in range(len(params)) else "none (no such parameter)"
                raise InputError(f"{path}: optimizer.state[{i}].{key} is {_describe(moment)}; the model's parameter "
                                 f"{i} has shape {shape}.")


# How each annotation of a settings dataclass is stored in a checkpoint, and said in a sentence.
_SETTING_KINDS = {
    "int": ((int,), "a whole number"), "float": ((int, float), "a finite number"), "bool": ((bool,), "true or false"),
    "str": ((str,), "text"), "Path": ((str,), "a path"), "None": ((type(None),), "none"),
    "NetworkConfig": ((dict,), "a table of layer sizes"),
}


def _check_setting_types(stored: dict, settings: type, path) -> None:
    """Each stored setting that `settings` declares is of a declared type (numbers finite)."""
    for f in fields(settings):
        if f.name not in stored:
            continue  # a setting added since the checkpoint was written
        names = [n.strip() for n in str(f.type).split("|")]
        kinds = [_SETTING_KINDS.get(n, ((object,), n)) for n in names]
        types = tuple(t for k in kinds for t in k[0])
        value = stored[f.name]
        wrong_type = (isinstance(value, bool) and bool not in types) or not isinstance(value, types)
        if wrong_type or (isinstance(value, float) and not math.isfinite(value)):
            raise InputError(f"{path}: train.{f.name} = {checks.show(value)} must be {' or '.join(k[1] for k in kinds)}.")


def _check_table(table: dict, known: set[str], where: str, path, require: bool = False) -> None:
    unknown = sorted(set(map(str, table)) - known)
    if unknown:
        raise InputError(f"{path}: unknown key '{unknown[0]}' in the checkpoint's {where}; known keys are {', '.join(sorted(known))}.")
    missing = sorted(known - set(table)) if require else []
    if missing:
        raise InputError(f"{path}: the checkpoint's {where} lacks the key '{missing[0]}'.")


def check_schema(simulator: GraphNetworkSimulator, data_schema: FeatureSchema, model_source, data_source) -> None:
    """Raise InputError naming the first difference between a model's and the data's schema."""
    diff = simulator.schema.difference(data_schema)
    if diff is not None:
        raise InputError(
            f"{model_source} does not fit {data_source}: {diff}"
            + (" (fine-tune with --init to widen the material inputs)." if "material_features" in diff else ".")
        )
