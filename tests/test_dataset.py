"""GNS dataset files: both layouts round-trip, malformed files fail with one clear sentence."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from runout.cli.app import app
from runout.dataset import summarize
from runout.errors import InputError
from runout.simfiles import REQUIRED_METADATA, read_metadata, read_simulations, statistics, write_metadata, write_simulations


def _sim(rng, frames=9, points=5, width=2):
    positions = rng.normal(size=(frames, points, 2)).cumsum(axis=0).astype(np.float32)
    ptype = np.where(np.arange(points) < 2, 3, 6).astype(np.int64)
    material = rng.uniform(size=(points, width)).astype(np.float32) if width else None
    return positions, ptype, material


def _same(a, b):
    for (pa, ta, ma), (pb, tb, mb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa, pb)
        np.testing.assert_array_equal(ta, tb)
        if ma is None:
            assert mb is None
        else:
            np.testing.assert_array_equal(ma, mb)


def _write_dataset(directory, widths=(2, 2, 2), rng=None):
    rng = rng or np.random.default_rng(0)
    directory.mkdir(exist_ok=True)
    sims = {}
    for name, w in zip(("train", "valid", "test"), widths):
        sims[name] = [_sim(rng, width=w), _sim(rng, frames=11, points=7, width=w)]
        write_simulations(directory / f"{name}.npz", sims[name])
    meta = statistics(sims["train"])
    meta["material_features"] = ["tan_phi", "c_over_100kPa"]
    write_metadata(directory / "metadata.json", meta)
    return sims


@pytest.mark.parametrize("layout", ["dict", "gns_data"])
@pytest.mark.parametrize("compress", [True, False])
def test_both_layouts_round_trip(tmp_path, layout, compress):
    rng = np.random.default_rng(1)
    sims = [_sim(rng), _sim(rng, frames=12, points=3), _sim(rng, points=4)]
    path = tmp_path / "train.npz"
    write_simulations(path, sims, layout=layout, compress=compress)
    _same(read_simulations(path), sims)
    with np.load(path, allow_pickle=True) as archive:
        assert (archive.files == ["gns_data"]) == (layout == "gns_data")


def test_simulations_without_material_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    sims = [_sim(rng, width=0), _sim(rng, width=0)]
    write_simulations(tmp_path / "a.npz", sims)
    _same(read_simulations(tmp_path / "a.npz"), sims)


def test_public_gns_file_with_scalar_type_and_flat_material_is_read(tmp_path):
    positions = np.zeros((8, 4, 2), dtype=np.float64)
    np.savez(tmp_path / "gns.npz", simulation_0=np.array([positions, 6, np.full(4, 0.5)], dtype=object))
    (pos, ptype, material), = read_simulations(tmp_path / "gns.npz")
    assert pos.dtype == np.float32 and ptype.tolist() == [6] * 4 and material.shape == (4, 1)


def _save_raw(path, item):
    np.savez(path, simulation_0=np.array(item, dtype=object))


@pytest.mark.parametrize(
    "item, message",
    [
        ((np.zeros((8, 4, 3)), np.full(4, 6)), "expected [T >= 7, N, 2]"),
        ((np.zeros((3, 4, 2)), np.full(4, 6)), "expected [T >= 7, N, 2]"),
        ((np.zeros((8, 4, 2)), np.full(5, 6)), "particle_type has shape (5,)"),
        ((np.full((8, 4, 2), np.nan), np.full(4, 6)), "NaN"),
        ((np.zeros((8, 4, 2)), np.full(4, 6), np.full((4, 1), np.inf)), "NaN or infinite"),
        ((np.zeros((8, 4, 2)), np.full(4, 6), np.zeros((3, 1))), "material has shape"),
    ],
)
def test_malformed_simulations_are_named(tmp_path, item, message):
    path = tmp_path / "bad.npz"
    _save_raw(path, item)
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        read_simulations(path)


def test_not_an_npz_file_is_an_input_error(tmp_path):
    path = tmp_path / "junk.npz"
    path.write_text("not a zip")
    with pytest.raises(InputError, match="not a readable npz"):
        read_simulations(path)
    with pytest.raises(InputError, match="no such dataset file"):
        read_simulations(tmp_path / "missing.npz")


def test_material_width_must_agree_within_a_split(tmp_path):
    rng = np.random.default_rng(3)
    write_simulations(tmp_path / "mixed.npz", [_sim(rng, width=2), _sim(rng, width=1)])
    with pytest.raises(InputError, match="simulation 1 has 1 material features but simulation 0 has 2"):
        read_simulations(tmp_path / "mixed.npz")


def test_material_width_must_agree_between_splits(tmp_path):
    _write_dataset(tmp_path / "ds", widths=(2, 2, 1))
    with pytest.raises(InputError, match="test has 1 material features but train has 2"):
        summarize(tmp_path / "ds")


def test_metadata_feature_names_must_match_the_files(tmp_path):
    _write_dataset(tmp_path / "ds", widths=(1, 1, 1))
    with pytest.raises(InputError, match="metadata.json has 2 material features but train has 1"):
        summarize(tmp_path / "ds")


@pytest.mark.parametrize("missing", REQUIRED_METADATA)
def test_missing_metadata_key_is_named(tmp_path, missing):
    _write_dataset(tmp_path / "ds")
    meta = json.loads((tmp_path / "ds" / "metadata.json").read_text())
    del meta[missing]
    (tmp_path / "ds" / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=f"missing required key '{missing}'"):
        read_metadata(tmp_path / "ds")


def test_split_metadata_of_the_public_code_is_read(tmp_path):
    _write_dataset(tmp_path / "ds")
    flat = json.loads((tmp_path / "ds" / "metadata.json").read_text())
    (tmp_path / "ds" / "metadata.json").write_text(json.dumps({"train": flat, "rollout": flat}))
    assert read_metadata(tmp_path / "ds")["vel_std"] == flat["vel_std"]


def test_statistics_equal_a_direct_recomputation():
    rng = np.random.default_rng(4)
    sims = [_sim(rng), _sim(rng, frames=13, points=6)]
    meta = statistics(sims)
    vel = np.concatenate([np.diff(p.astype(np.float64), axis=0).reshape(-1, 2) for p, _, _ in sims])
    acc = np.concatenate([np.diff(p.astype(np.float64), n=2, axis=0).reshape(-1, 2) for p, _, _ in sims])
    np.testing.assert_allclose(meta["vel_mean"], vel.mean(axis=0), rtol=1e-10)
    np.testing.assert_allclose(meta["vel_std"], vel.std(axis=0), rtol=1e-8)
    np.testing.assert_allclose(meta["acc_mean"], acc.mean(axis=0), rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(meta["acc_std"], acc.std(axis=0), rtol=1e-8)
    assert meta["sequence_length"] == 13


def test_inspect_prints_counts_frames_points_and_statistics(tmp_path):
    _write_dataset(tmp_path / "ds")
    result = CliRunner().invoke(app, ["inspect", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    assert "train: 2 simulations, frames 9-11, points 5-7 (4 of 12 kinematic)" in result.output
    assert "vel_std" in result.output and "acc_mean" in result.output
    one = CliRunner().invoke(app, ["inspect", str(tmp_path / "ds" / "valid.npz")])
    assert "valid: 2 simulations" in one.output
