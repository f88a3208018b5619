"""Does a refactoring leave the GNS's figures unchanged, bit for bit? Prints with full precision:

1. the held-out measure of a model on the first 2 valid scenes of a dataset from rest
   (runout.evaluate.heldout.evaluate_heldout): position error of the model and of standing
   still, front error;
2. `runout compare`'s fronts and position MSE on one scene (run_compare, MPM from a cache);
3. the inverse's first evaluation through the GNS (loss and gradient) for the demo's small-dam
   spec: c of the lower downstream shell free, starting at 70 kPa, the MPM's deposit as target;
4. the loss of the first step after a resume: a tiny run of the recipe's settings trained 2 steps
   on 2 scenes of the dataset, then resumed for one more; and the first step of the model's own
   resume file (models/slope-train.pt) resumed on those 2 scenes.

Run it before and after a change and diff the outputs (issue 53 item 4):

    PYTHONPATH=src .venv/bin/python experiments/gns_fingerprint.py --data data/ft8 --work /tmp/fp > before.txt
"""

from __future__ import annotations

import argparse
import json
import shutil
from dataclasses import fields
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]


def heldout(model: Path, data: Path) -> list[str]:
    from runout.evaluate.heldout import evaluate_heldout
    from runout.learned.load import load_engine

    result = evaluate_heldout(load_engine(model, "cpu"), data, "valid", 2)
    return [f"heldout position error model {result['model']['position_error_m']!r} m",
            f"heldout position error standing still {result['standing_still']['position_error_m']!r} m",
            f"heldout front error {result['model']['front_error']!r}"]


def compare(model: Path, scene: Path, work: Path, cache) -> list[str]:
    from runout.compare import run_compare

    metrics = run_compare(scene, model, work / "compare", cache=cache, force=True, progress=False,
                          log=lambda _: None, warn=lambda _: None).metrics
    lines = [f"compare {side} truth {metrics[side]['truth']!r} predicted {metrics[side]['predicted']!r}"
             for side in ("runout_left_m", "runout_right_m", "runout_farthest_m")]
    return lines + [f"compare position MSE mean {metrics['position_mse_mean_m2']!r} final {metrics['position_mse_final_m2']!r}",
                    f"compare deposit IoU {metrics['deposit_iou']!r}"]


SPEC = """scene = "scene.toml"

[target]
trajectory = "{target}"
frames = "final"

[parameters.m1_downstream_lower]
phi = {{ fixed = {phi:g} }}
c = {{ initial = 70.0, lower = 10.0, upper = 100.0 }}

[optimiser]
max_iterations = 1
max_evaluations = 2
gtol = 1e6
"""


def inverse(model: Path, work: Path, cache) -> list[str]:
    from runout.inverse import invert
    from runout.learned.load import load_engine
    from runout.learned.scenes import at_model_spacing
    from runout.scene import load_scene, save_scene

    scene = at_model_spacing(load_scene(REPO / "examples" / "small_dam.toml"), load_engine(model, "cpu"), "dam", None)
    folder = work / "inverse"
    folder.mkdir(parents=True, exist_ok=True)
    save_scene(scene, folder / "scene.toml")
    target = cache.ensure([scene], progress=False)[0]
    (folder / "spec.toml").write_text(SPEC.format(target=target.as_posix(), phi=scene.materials["m1_downstream_lower"].friction_angle))
    invert(folder / "spec.toml", folder / "out", model=model, force=True)
    first = json.loads((folder / "out" / "history.json").read_text())["evaluations"][0]
    return [f"inverse first loss {first['loss']!r}", f"inverse first gradient {first['gradient']!r}"]


def tiny_dataset(data: Path, work: Path) -> Path:
    """2 valid scenes of DATA, their first 40 frames, as train.npz beside DATA's metadata.json."""
    from runout.simfiles import read_simulations, write_simulations

    tiny = work / "tiny"
    if tiny.exists():
        shutil.rmtree(tiny)
    tiny.mkdir(parents=True)
    sims = read_simulations(data / "valid.npz")[:2]
    write_simulations(tiny / "train.npz", [(p[:40], t, m) for p, t, m in sims])
    meta = json.loads((data / "metadata.json").read_text())
    (tiny / "metadata.json").write_text(json.dumps({k: v for k, v in meta.items() if k not in ("splits", "scene_families")}))
    return tiny


RECIPE = dict(lr_init=4e-4, lr_decay_steps=200_000.0, noise=0.01, exact_rest=True, pushforward=2, ema=0.999,
              checkpoint_layers=False, onset_schedule=((0, 0.4, 4), (1, 0.5, 2), (2, 0.1, 4)), overburden=True,
              mirror=0.5, batch_size=2, seed=0, device="cpu", progress=False, save_every=1, log_every=1, valid_every=0)


def losses_of(cfg) -> list[float]:
    from runout.train import train

    seen = []
    train(cfg, hooks=(lambda trainer: seen.append(trainer.losses[-1].item()),))
    return seen


def resumed_steps(tiny: Path, work: Path, resume_file: Path) -> list[str]:
    from runout.train import TrainConfig

    known = {f.name for f in fields(TrainConfig)}
    network = type(TrainConfig(tiny, work).network)(latent=16, hidden=16, hidden_layers=2, message_passing_steps=2)
    run = work / "tiny-run"
    shutil.rmtree(run, ignore_errors=True)
    torch.manual_seed(0)
    first = losses_of(TrainConfig(tiny, run, steps=2, network=network, **RECIPE))
    resumed = losses_of(TrainConfig(tiny, run, steps=3, network=network, resume=True, **RECIPE))
    lines = [f"tiny run losses {first!r}, resumed step {resumed!r}"]

    own = work / "own-run"
    shutil.rmtree(own, ignore_errors=True)
    own.mkdir()
    shutil.copyfile(resume_file, own / "checkpoint.pt")
    stored = torch.load(own / "checkpoint.pt", weights_only=True, map_location="cpu")
    settings = {k: v for k, v in stored["train"].items() if k in known and k not in ("data", "out", "network", "init")}
    settings.update(steps=stored["step"] + 1, resume=True, device="cpu", progress=False, valid_every=0, max_hours=0.0)
    lines.append(f"{resume_file.name} resumed step {losses_of(TrainConfig(tiny, own, **settings))!r}")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=REPO / "data" / "ft8")
    ap.add_argument("--model", type=Path, default=REPO / "models" / "slope.pt")
    ap.add_argument("--resume-file", type=Path, default=REPO / "models" / "slope-train.pt")
    ap.add_argument("--scene", type=Path, default=REPO / "examples" / "small_dam.toml")
    ap.add_argument("--work", type=Path, required=True, help="a scratch folder; its MPM cache is kept between runs")
    args = ap.parse_args()
    from runout.mpm.cache import MpmCache

    torch.set_num_threads(1)
    cache = MpmCache(args.work / "mpm-cache")
    lines = heldout(args.model, args.data)
    lines += compare(args.model, args.scene, args.work, cache)
    lines += inverse(args.model, args.work, cache)
    lines += resumed_steps(tiny_dataset(args.data, args.work), args.work, args.resume_file)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
