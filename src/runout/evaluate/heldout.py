"""Held-out scenes rolled out from rest, the way users run a model, scored against the MPM and
beside a prediction in which nothing moves (standing still): the measure of every training
pilot and campaign chunk (docs/training.md).

Per scene, at the times the two trajectories share (runout.metrics.at_common_times):

- position error (m): the distance between the engine's and the MPM's positions of every soil
  point, averaged over every point and shared frame;
- front error: for each side (the leftmost and the rightmost soil point at the last shared
  frame) |x_predicted - x_MPM| over the MPM front's travel from frame 0, for the sides whose front
  travels more than MIN_TRAVEL_SPACINGS point spacings (standing still scores 1 on every one);
- extent runout error: |L_predicted - L_MPM| / L_MPM of the soil's horizontal extent at the last
  frame;
- mean displacement (m) of the soil at the last frame, the engine's and the MPM's.

`score` averages them over the scenes; `evaluate_heldout` also averages them by kind of scene
(`by_kind`): the dataset's family of each scene (metadata.json's scene_families through its
splits) and whether it starts at rest or with thrown soil (points faster than START_SPEED at
frame 0), since a model can start failing slopes badly and thrown blocks well, or the reverse.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from runout.metrics import compare, final_displacement, front_errors
from runout.trajectory import Trajectory

MIN_TRAVEL_SPACINGS = 1.0  # a front that travels less than this many point spacings is not scored


def standing_still(truth: Trajectory) -> Trajectory:
    """A prediction in which nothing moves: the truth's frame 0 held for every frame."""
    frozen = np.repeat(truth.positions[:1], truth.n_frames, axis=0)
    return replace(truth, positions=frozen, info=dict(truth.info))


def scene_scores(predicted: Trajectory, truth: Trajectory, spacing: float) -> dict:
    """The scores of one scene (module docstring); spacing: the points' spacing (m)."""
    fronts = front_errors(predicted, truth)
    relative = [abs(fronts[f"{side}_front_error_m"]) / fronts[f"{side}_front_travel_m"]
                for side in ("left", "right") if fronts[f"{side}_front_travel_m"] > MIN_TRAVEL_SPACINGS * spacing]
    return {
        "name": truth.name,
        "position_error_m": fronts["position_error_mean_m"],
        "front_errors": relative,
        "runout_error": abs(compare(predicted, truth)["runout_error"]),
        "displacement_m": float(final_displacement(predicted).mean()),
        "displacement_mpm_m": float(final_displacement(truth).mean()),
    }


def score(predicted: list[Trajectory], truths: list[Trajectory], spacing: float) -> dict:
    """Means over the scenes, and each scene's scores under "per_scene"."""
    return summarise([scene_scores(p, t, spacing) for p, t in zip(predicted, truths)])


def summarise(scenes: list[dict]) -> dict:
    """Means of scene_scores over the scenes, and the scenes under "per_scene"."""
    fronts = [e for s in scenes for e in s["front_errors"]]
    return {
        "scenes": len(scenes),
        "position_error_m": float(np.mean([s["position_error_m"] for s in scenes])),
        "front_error": float(np.mean(fronts)) if fronts else float("nan"),
        "fronts_scored": len(fronts),
        "runout_error": float(np.mean([s["runout_error"] for s in scenes])),
        "displacement_m": float(np.mean([s["displacement_m"] for s in scenes])),
        "displacement_mpm_m": float(np.mean([s["displacement_mpm_m"] for s in scenes])),
        "per_scene": scenes,
    }


def evaluate_heldout(engine, data: str | Path, split: str = "valid", count: int = 16, progress: bool = False,
                     mirrored: bool = False) -> dict:
    """The first `count` scenes of DATA/SPLIT.npz rolled out from rest over all their frames:
    {"model": score(...), "standing_still": score(...)}. mirrored: each scene and its MPM run
    reflected left-right (Trajectory.mirrored), which a model that learned the physics rather
    than the side the training slopes face scores as it scores them unreflected. engine: any
    learned engine (runout.learned.engine)."""
    from runout.dataset import split_trajectories
    truths = list(split_trajectories(data, split, count))
    if mirrored:
        truths = [t.mirrored() for t in truths]
    spacing = engine.point_spacing
    predicted = rollout_all(engine, truths, progress)
    result = {"model": score(predicted, truths, spacing),
              "standing_still": score([standing_still(t) for t in truths], truths, spacing)}
    kinds = scene_kinds(data, split, truths)
    result["by_kind"] = {
        kind: {who: _without_scenes(summarise([s for s, k in zip(result[who]["per_scene"], kinds[group]) if k == kind]))
               for who in ("model", "standing_still")}
        for group in ("family", "start") for kind in sorted(set(kinds[group]) - {None})
    }
    return result


def _without_scenes(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k != "per_scene"}


def scene_kinds(data: str | Path, split: str, truths: list[Trajectory]) -> dict[str, list[str | None]]:
    """Each truth's kind, by "family" ("family b", ...: metadata.json's scene_families through
    its splits; None where the dataset does not record them) and by "start" ("starts at rest",
    "starts thrown": soil faster than START_SPEED at frame 0). truths: the split's first
    scenes, in order."""
    from runout.dataset import read_metadata

    meta = read_metadata(Path(data))
    families, order = meta.get("scene_families"), (meta.get("splits") or {}).get(split)
    by_family = [f"family {families[order[i]]}" if families and order and i < len(order) else None
                 for i in range(len(truths))]
    by_start = ["starts thrown" if t.start_velocity().any() else "starts at rest" for t in truths]
    return {"family": by_family, "start": by_start}


def rollout_all(engine, truths, progress: bool = False) -> list:
    """Every truth rolled out from rest over all its frames, one scene at a time: batching
    the GNS's scenes (runout.gns.rollout.rollout_trajectories) was slower on the 2-core CPU (8
    validation scenes, 60 frames: 331 s against 254 s, 1 thread, loaded, 2026-12-03).
    progress: one bar over the scenes on stderr."""
    from tqdm.auto import tqdm

    return [engine.rollout_trajectory(t, t.n_frames, stop_speed=None)
            for t in tqdm(truths, disable=not progress, desc="held-out rollouts from rest", unit="scene")]
