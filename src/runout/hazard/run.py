"""A Monte Carlo runout study, run in batches through the batched MPM, resumable and shardable.

Layout of a study folder OUT:

    OUT/hazard.json            what the study is (the spec's values): a resumed run must match it
    OUT/parts/part_00003.npz   finished batches (batch j = realisations j*B .. j*B+B-1), each written
                               atomically: indices, inputs, front runouts, thickness profiles
    OUT/realisations.csv, ...  the results (runout.hazard.results), written when every part exists

Realisation k's strengths depend only on the spec (runout.hazard.sampling) and batch j always
holds the same realisations, so a killed run that is started again recomputes no finished
batch and ends with the same numbers; shards (`shard=(i, n)`) run batches j with j mod n == i,
and `merge` joins their parts into what an unsharded run writes.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from runout.errors import InputError, RunFailed
from runout.hazard.deposit import bin_count, front_runouts, thickness_profile
from runout.hazard.sampling import draw_inputs
from runout.hazard.spec import HazardSpec
from runout.npz import SafeNpz, numeric
from runout.outputs import write_atomic
from runout.reading import read_json
from runout.scene import Scene

Simulate = Callable[..., list]  # runout.mpm.simulate(scenes, device=..., progress=...)


def realisation_scene(spec: HazardSpec, k: int, values: np.ndarray) -> Scene:
    """The scene of realisation k with its strengths (φ degrees, c kPa) in spec.inputs() order."""
    changes: dict[str, dict] = {}
    for (material, prop), value in zip(spec.inputs(), values):
        changes.setdefault(material, {})["friction_angle" if prop == "phi" else "cohesion"] = float(value)
    return replace(spec.scene.with_materials(**changes), name=f"{spec.scene.name}_{k:05d}")


def run_study(spec: HazardSpec, out: str | Path, shard: tuple[int, int] = (0, 1), device: str = "cpu",
              simulate: Simulate | None = None, progress: bool = True) -> list[int]:
    """Run this shard's unfinished batches into out/parts; returns the batches it ran."""
    from runout.mpm.budget import check_budget

    if simulate is None:
        from runout.mpm import simulate
    out = Path(out)
    claim_study(out, spec)
    inputs = draw_inputs(spec)
    mine = [j for j in range(spec.n_batches) if j % shard[1] == shard[0]]
    todo = [j for j in mine if not part_path(out, j).is_file()]
    for j in (j for j in mine if j not in todo):
        read_part(part_path(out, j), spec, j, inputs)
    check_budget([spec.scene] * spec.batch, device=device, source=f"a batch of {spec.batch} realisations")
    with tqdm(total=len(mine), initial=len(mine) - len(todo), desc="hazard", unit="batch", disable=not progress) as bar:
        for j in todo:
            _run_batch(spec, out, j, inputs, simulate, device)
            bar.update(1)
    return todo


def _run_batch(spec: HazardSpec, out: Path, j: int, inputs: np.ndarray, simulate: Simulate, device: str) -> None:
    indices = spec.batch_indices(j)
    scenes = [realisation_scene(spec, k, inputs[k]) for k in indices]
    trajs = simulate(scenes, device=device, progress=False)
    for k, traj in zip(indices, trajs):
        if traj.first_nonfinite_frame() is not None:
            raise RunFailed(f"realisation {k} diverged (positions not finite); the finished batches in {out / 'parts'} are kept.")
    spacing = spec.scene.domain.point_spacing
    bins = bin_count(spec.scene.domain.width, spec.bin_width)
    write_part(part_path(out, j), {
        "indices": np.asarray(indices, dtype=np.int64),
        "inputs": inputs[indices.start:indices.stop],
        "runouts": np.stack([front_runouts(t) for t in trajs]),  # m, [B, 2]
        "thickness": np.stack([thickness_profile(t, spacing, spec.bin_width, bins) for t in trajs]),  # m, [B, J]
        "device": np.asarray(device),
    })


def part_path(out: Path, j: int) -> Path:
    return out / "parts" / f"part_{j:05d}.npz"


def write_part(path: Path, arrays: dict) -> None:
    """Write then rename: a killed run never leaves half a part."""
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def read_part(path: Path, spec: HazardSpec, j: int, inputs: np.ndarray) -> dict:
    """A finished part's arrays, checked to be batch j's realisations with the spec's strengths."""
    with SafeNpz(path) as part:
        arrays = {key: numeric(part[key], key, path) for key in ("indices", "inputs", "runouts", "thickness")}
    indices = spec.batch_indices(j)
    if arrays["indices"].tolist() != list(indices) or not np.array_equal(arrays["inputs"], inputs[indices.start:indices.stop]):
        raise InputError(f"{path}: holds other realisations than batch {j} of this spec; remove it and run the "
                         "same command to redo the batch.")
    return arrays


def claim_study(out: Path, spec: HazardSpec) -> None:
    """Create out/ with hazard.json, or check that the one there records the same study."""
    (out / "parts").mkdir(parents=True, exist_ok=True)
    path = out / "hazard.json"
    record = spec.record()
    if path.is_file():
        if read_json(path, "hazard record") != json.loads(json.dumps(record)):
            raise InputError(f"{path}: this folder holds a different hazard study; use a new --out (or --force to start afresh).")
        return
    write_atomic(path, json.dumps(record, indent=2) + "\n")


def gather(spec: HazardSpec, dirs: list[Path]) -> dict[str, np.ndarray]:
    """Every realisation's inputs, runouts and thickness, in order, from the parts of `dirs`."""
    inputs = draw_inputs(spec)
    parts = []
    for j in range(spec.n_batches):
        found = next((part_path(d, j) for d in dirs if part_path(d, j).is_file()), None)
        if found is None:
            raise InputError(f"batch {j} of {spec.n_batches} is not finished (no part_{j:05d}.npz in "
                             f"{', '.join(map(str, dirs))}); run the missing shards, then merge.")
        parts.append(read_part(found, spec, j, inputs))
    return {key: np.concatenate([p[key] for p in parts]) for key in ("inputs", "runouts", "thickness")}
