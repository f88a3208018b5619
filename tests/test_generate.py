"""Dataset generation: deterministic, resumable, shardable, statistics that recompute.

Pipeline tests use a cheap stand-in for the MPM (points thrown ballistically and clamped
to the domain), so they check the bookkeeping, not the physics; one test runs the real
MPM through the command line on coarse cells and a few frames.
"""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from runout.cli.app import app
from runout.dataset import summarize
from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.errors import InputError
from runout.generate import GenerateConfig, generate, merge, parse_shard, split_of
from runout.scene import fill_points, load_scene
from runout.simfiles import read_metadata, read_simulations
from runout.trajectory import trajectory_for_scene

CONFIG = GenerateConfig(stage="finetune", count=12, seed=3, batch=4, frames=8, cell_size=10.0)


class Ballistic:
    """Stand-in MPM: soil points fly from their initial velocity under gravity and a light
    sideways pull (so both velocity components spread, as in any flow, and the metadata's
    std are above zero), clamped to the domain; ground points stay. Counts the scenes it is
    asked to run."""

    def __init__(self, fail_after_batches: int | None = None):
        self.scenes_run: list[str] = []
        self.fail_after = fail_after_batches
        self.batches = 0

    def __call__(self, scenes, device="cpu", progress=True):
        if self.fail_after is not None and self.batches == self.fail_after:
            raise KeyboardInterrupt
        self.batches += 1
        out = []
        for s in scenes:
            self.scenes_run.append(s.name)
            p = fill_points(s)
            t = np.arange(s.time.frames)[:, None, None] * s.time.frame_dt
            x = p.position[None] + p.velocity[None] * t + 0.5 * np.array([1.0, -9.81]) * t**2
            x[:, p.fixed] = p.position[p.fixed]
            x = np.clip(x, 0.0, [s.domain.width, s.domain.height])
            out.append(trajectory_for_scene(s, x, p.particle_type, p.material_id))
        return out


def _dataset(directory):
    return {name: read_simulations(directory / f"{name}.npz") for name in ("train", "valid", "test")}


def _assert_same_dataset(a, b):
    da, db = _dataset(a), _dataset(b)
    for name in da:
        assert len(da[name]) == len(db[name])
        for sa, sb in zip(da[name], db[name]):
            for xa, xb in zip(sa, sb):
                np.testing.assert_array_equal(xa, xb)
    ma = json.loads((a / "metadata.json").read_text())
    mb = json.loads((b / "metadata.json").read_text())
    assert ma == mb


def test_generate_writes_gns_splits_scenes_and_metadata(tmp_path):
    sim = Ballistic()
    assert generate(CONFIG, tmp_path, simulate=sim, progress=False)
    meta = read_metadata(tmp_path)
    assert meta["splits"] == {"train": [0, 1, 2, 3, 4, 5, 6, 7, 10, 11], "valid": [8], "test": [9]}
    assert meta["material_features"] == ["tan_phi", "c_over_100kPa"]
    assert meta["stage"] == "finetune" and meta["seed"] == 3 and meta["count"] == 12
    assert meta["bounds"] == [[0.0, 400.0], [0.0, 152.0]]
    assert meta["default_connectivity_radius"] == pytest.approx(2.3 * 5.0)
    assert meta["ranges"]["cohesion_kpa"] == [10.0, 60.0] and "undrained_share" not in meta["ranges"]
    assert sum(meta["family_counts"].values()) == 12 and set(meta["family_counts"]) <= {"b", "c", "d", "column"}
    assert meta["code_version"].startswith("0.")
    sims = _dataset(tmp_path)
    assert [len(sims[n]) for n in ("train", "valid", "test")] == [10, 1, 1]
    # simulation 0 of the test split is scene 9: its file re-creates its first frame
    scene = load_scene(tmp_path / "scenes" / "scene_00009.toml")
    positions, ptype, material = sims["test"][0]
    pts = fill_points(scene)
    np.testing.assert_allclose(positions[0], pts.position, atol=1e-4)
    np.testing.assert_array_equal(ptype, pts.particle_type)
    mats = [scene.materials[n] for n in scene.material_names]
    expected = np.array([[np.tan(np.radians(m.friction_angle)), m.cohesion / 100] for m in mats])[pts.material_id]
    np.testing.assert_allclose(material, expected, rtol=1e-6)


def test_base_stage_has_one_material_feature(tmp_path):
    config = GenerateConfig(stage="base", count=10, seed=0, batch=5, frames=7, cell_size=10.0)
    generate(config, tmp_path, simulate=Ballistic(), progress=False)
    assert read_metadata(tmp_path)["material_features"] == ["tan_phi"]
    assert all(s[2].shape[1] == 1 for s in read_simulations(tmp_path / "train.npz"))
    assert summarize(tmp_path)["splits"]["train"]["material_width"] == 1


def test_the_dams_stage_records_its_ranges_and_undrained_share(tmp_path):
    config = GenerateConfig(stage="dams", count=10, seed=0, batch=5, frames=7, cell_size=10.0)
    generate(config, tmp_path, simulate=Ballistic(), progress=False)
    meta = read_metadata(tmp_path)
    ranges = meta["ranges"]
    assert ranges["friction_angle_deg"] == [0.0, 45.0] and ranges["cohesion_kpa"] == [0.0, 110.0]
    assert ranges["domain_m"] == [800.0, 100.0] and ranges["undrained_share"] == 0.25 and ranges["vertices_m"] == {}
    assert ranges["zoned_dam"]["excluded_base_height_crest_m"] == [260.0, 60.0, 20.0]
    assert meta["family_counts"] == {"zoned_dam": 10} and meta["material_features"] == ["tan_phi", "c_over_100kPa"]


def test_statistics_equal_a_direct_recomputation_over_the_train_split(tmp_path):
    generate(CONFIG, tmp_path, simulate=Ballistic(), progress=False)
    train = read_simulations(tmp_path / "train.npz")
    vel = np.concatenate([np.diff(p.astype(np.float64), axis=0).reshape(-1, 2) for p, _, _ in train])
    acc = np.concatenate([np.diff(p.astype(np.float64), n=2, axis=0).reshape(-1, 2) for p, _, _ in train])
    meta = read_metadata(tmp_path)
    np.testing.assert_allclose(meta["vel_mean"], vel.mean(axis=0), rtol=1e-9)
    np.testing.assert_allclose(meta["vel_std"], vel.std(axis=0), rtol=1e-9)
    np.testing.assert_allclose(meta["acc_mean"], acc.mean(axis=0), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(meta["acc_std"], acc.std(axis=0), rtol=1e-9)
    assert meta["sequence_length"] == CONFIG.frames


def test_a_killed_run_resumes_without_redoing_finished_batches(tmp_path):
    generate(CONFIG, tmp_path / "whole", simulate=Ballistic(), progress=False)
    with pytest.raises(KeyboardInterrupt):
        generate(CONFIG, tmp_path / "killed", simulate=Ballistic(fail_after_batches=2), progress=False)
    assert len(list((tmp_path / "killed" / "parts").glob("part_*.npz"))) == 2
    assert not (tmp_path / "killed" / "train.npz").exists()
    rest = Ballistic()
    assert generate(CONFIG, tmp_path / "killed", simulate=rest, progress=False)
    assert rest.scenes_run == [f"scene_{k:05d}" for k in range(8, 12)]
    _assert_same_dataset(tmp_path / "whole", tmp_path / "killed")


def test_merged_shards_equal_an_unsharded_run(tmp_path):
    generate(CONFIG, tmp_path / "whole", simulate=Ballistic(), progress=False)
    runs = [Ballistic(), Ballistic()]
    for i, sim in enumerate(runs):
        assert not generate(CONFIG, tmp_path / f"shard{i}", shard=(i, 2), simulate=sim, progress=False)
    assert runs[0].scenes_run[:4] == ["scene_00000", "scene_00001", "scene_00002", "scene_00003"]
    assert set(runs[0].scenes_run).isdisjoint(runs[1].scenes_run)
    merge([tmp_path / "shard0", tmp_path / "shard1"], tmp_path / "merged")
    _assert_same_dataset(tmp_path / "whole", tmp_path / "merged")
    assert len(list((tmp_path / "merged" / "scenes").glob("*.toml"))) == CONFIG.count


def test_merge_refuses_missing_batches_and_foreign_shards(tmp_path):
    generate(CONFIG, tmp_path / "s0", shard=(0, 2), simulate=Ballistic(), progress=False)
    with pytest.raises(InputError, match="batches are not finished"):
        merge([tmp_path / "s0"], tmp_path / "out")
    other = GenerateConfig(**{**CONFIG.__dict__, "seed": 4})
    generate(other, tmp_path / "s1", shard=(1, 2), simulate=Ballistic(), progress=False)
    with pytest.raises(InputError, match="only shards of one run merge"):
        merge([tmp_path / "s0", tmp_path / "s1"], tmp_path / "out2")


def test_a_directory_holds_one_dataset(tmp_path):
    generate(CONFIG, tmp_path, shard=(0, 3), simulate=Ballistic(), progress=False)
    with pytest.raises(InputError, match="holds a different dataset"):
        generate(GenerateConfig(**{**CONFIG.__dict__, "count": 13}), tmp_path, simulate=Ballistic(), progress=False)


def test_configs_and_shards_are_checked():
    with pytest.raises(InputError, match="at least 10"):
        GenerateConfig("base", 5, 0).check()
    with pytest.raises(InputError, match="stage"):
        GenerateConfig("huge", 100, 0).check()
    assert parse_shard("1/4") == (1, 4)
    with pytest.raises(InputError, match="shard index"):
        parse_shard("4/4")
    assert [split_of(k) for k in range(10)].count("train") == 8


@pytest.mark.slow
def test_generate_command_runs_the_real_mpm(tmp_path):
    out = tmp_path / "ds"
    args = ["generate", "--stage", "base", "--count", "10", "--batch", "10", "--frames", "7",
            "--cell-size", "16", "--seed", "1", "--out", str(out)]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    summary = summarize(out)
    assert summary["splits"]["train"]["simulations"] == 8 and summary["splits"]["train"]["frames"] == [7, 7]
    (positions, ptype, _), = read_simulations(out / "test.npz")
    fixed = ptype == PARTICLE_TYPE_KINEMATIC
    assert np.array_equal(positions[0, fixed], positions[-1, fixed])
    shown = CliRunner().invoke(app, ["inspect", str(out)])
    assert "stage: base" in shown.output
