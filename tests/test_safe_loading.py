"""Files from elsewhere are opened without running what they carry: a checkpoint or .npz
whose pickled object would create a file when unpickled, a raw pickle named .npz, a corrupt
archive. Each is refused with one sentence (exit 2 on the command line) and nothing runs."""

import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from runout.cli import main
from runout.errors import InputError
from runout.gns.checkpoint import load_simulator, read_checkpoint
from runout.npz import SafeNpz
from runout.simfiles import read_simulations, write_simulations

REPO = Path(__file__).resolve().parents[1]
MODEL = REPO / "models" / "slope.pt"


class CreatesFile:
    """Unpickling this object opens (creates) `path`: a stand-in for any code a file could run."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def one_sentence(text: str) -> bool:
    text = text.strip()
    return "\n" not in text and text.endswith(".") and ". " not in text and "Traceback" not in text


def _sim(points=4, frames=8):
    positions = np.zeros((frames, points, 2), dtype=np.float32)
    return positions, np.full(points, 6, dtype=np.int64), np.full(points, 0.5, dtype=np.float32)


def evil_dict_npz(path, marker):
    item = np.empty(3, dtype=object)
    item[0], item[1], item[2] = np.zeros((8, 4, 2)), np.full(4, 6), CreatesFile(marker)
    np.savez(path, simulation_0=item)


def evil_gns_data_npz(path, marker):
    data = np.empty(1, dtype=object)
    data[0] = (np.zeros((8, 4, 2)), CreatesFile(marker), np.full(4, 0.5))
    np.savez(path, gns_data=data)


def test_the_malicious_npz_really_runs_code_under_a_plain_numpy_load(tmp_path):
    """The fixture is honest: numpy's own pickle loading creates the file."""
    marker = tmp_path / "ran"
    evil_dict_npz(tmp_path / "evil.npz", marker)
    with np.load(tmp_path / "evil.npz", allow_pickle=True) as archive:
        archive["simulation_0"]
    assert marker.exists()


@pytest.mark.parametrize("build", [evil_dict_npz, evil_gns_data_npz])
def test_a_pickled_object_in_an_npz_is_refused_and_never_run(tmp_path, build):
    marker = tmp_path / "ran"
    build(tmp_path / "evil.npz", marker)
    with pytest.raises(InputError) as err:
        read_simulations(tmp_path / "evil.npz")
    assert not marker.exists()
    assert "refused" in str(err.value) and "open" in str(err.value) and one_sentence(str(err.value))


def test_a_raw_pickle_named_npz_is_refused_and_never_run(tmp_path):
    marker = tmp_path / "ran"
    (tmp_path / "evil.npz").write_bytes(pickle.dumps(CreatesFile(marker)))
    with pytest.raises(InputError, match="not a readable npz file") as err:
        read_simulations(tmp_path / "evil.npz")
    assert not marker.exists() and one_sentence(str(err.value))


def test_a_crc_corrupt_npz_is_one_sentence(tmp_path):
    path = tmp_path / "train.npz"
    write_simulations(path, [_sim()], compress=False)
    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.infolist()[0]
    data[info.header_offset + 30 + len(info.filename) + 200] ^= 0xFF  # a byte inside the array
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="corrupt") as err:
        read_simulations(path)
    assert one_sentence(str(err.value))


def test_named_numeric_arrays_need_no_pickle(tmp_path):
    positions, ptype, material = _sim(points=5, frames=9)
    np.savez(tmp_path / "plain.npz", positions_0=positions, particle_type_0=ptype, material_0=material)
    (p, t, m), = read_simulations(tmp_path / "plain.npz")
    np.testing.assert_array_equal(p, positions)
    assert m.shape == (5, 1) and t.tolist() == [6] * 5


def test_a_non_numeric_member_is_refused(tmp_path):
    np.savez(tmp_path / "text.npz", positions_0=np.array(["a", "b"]), particle_type_0=np.zeros(2))
    with pytest.raises(InputError, match="not numeric"):
        read_simulations(tmp_path / "text.npz")


def test_object_arrays_of_numbers_are_read(tmp_path):
    positions, ptype, material = _sim()
    write_simulations(tmp_path / "ok.npz", [(positions, ptype, material[:, None])])
    with SafeNpz(tmp_path / "ok.npz") as archive:
        item = archive["simulation_0"]
    assert item.dtype == object and item[0].shape == (8, 4, 2)


def test_inspect_of_a_malicious_dataset_exits_2_with_one_sentence(tmp_path, capsys):
    marker = tmp_path / "ran"
    evil_dict_npz(tmp_path / "evil.npz", marker)
    with pytest.raises(SystemExit) as done:
        main(["inspect", str(tmp_path / "evil.npz")])
    assert done.value.code == 2 and not marker.exists()
    assert one_sentence(capsys.readouterr().err)


# ----------------------------------------------------------------------------- checkpoints


def test_the_shipped_model_loads_as_plain_data():
    ckpt = torch.load(MODEL, weights_only=True)
    assert ckpt["format"] == "runout-gns-1"
    assert load_simulator(MODEL).radius == ckpt["radius"]


def test_a_checkpoint_with_a_pickled_object_is_refused_and_never_run(tmp_path):
    marker = tmp_path / "ran"
    ckpt = dict(torch.load(MODEL, weights_only=True), sessions=CreatesFile(marker))
    torch.save(ckpt, tmp_path / "evil.pt")
    with pytest.raises(InputError) as err:
        read_checkpoint(tmp_path / "evil.pt")
    assert not marker.exists()
    assert "refused" in str(err.value) and "open" in str(err.value) and one_sentence(str(err.value))


def test_rollout_with_a_malicious_checkpoint_exits_2_and_runs_nothing(tmp_path, capsys):
    marker = tmp_path / "ran"
    torch.save({"format": "runout-gns-1", "model": CreatesFile(marker)}, tmp_path / "evil.pt")
    with pytest.raises(SystemExit) as done:
        main(["rollout", "--model", str(tmp_path / "evil.pt"), str(REPO / "examples" / "dam.toml"), "--out", str(tmp_path / "o")])
    assert done.value.code == 2 and not marker.exists()
    assert one_sentence(capsys.readouterr().err)


@pytest.mark.parametrize(
    "change, words",
    [
        ({"radius": -5.0}, "radius = -5 is outside the allowed range (0, 1000] m"),
        ({"radius": "far"}, "radius = 'far' must be a finite number in (0, 1000] m"),
        ({"network": {"latent": 0}}, "network.latent = 0 is outside the allowed range [1, 1024]"),
        ({"network": {"latent": 32, "width": 3}}, "unknown key 'width' in the checkpoint's network"),
        ({"schema": {"history": 1}}, "schema.history = 1 is outside"),
        ({"schema": {"material_features": ["density"]}}, "material_features = ['density']"),
        ({"stats": {"vel_mean": [0, 0]}}, "the checkpoint's stats lacks the key"),
        ({"stats": "none"}, "the checkpoint's 'stats' is a str"),
        ({"model": {"bogus": torch.zeros(2)}}, "the model weights do not match"),
    ],
)
def test_bad_checkpoint_entries_are_one_sentence(tmp_path, change, words):
    ckpt = torch.load(MODEL, weights_only=True)
    ckpt.update(change)
    torch.save(ckpt, tmp_path / "bad.pt")
    with pytest.raises(InputError) as err:
        load_simulator(tmp_path / "bad.pt")
    assert words in str(err.value) and one_sentence(str(err.value))
