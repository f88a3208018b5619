"""The plotting package draws without choosing a backend at import, through one writer."""

import subprocess
import sys

import numpy as np
from PIL import Image

from runout.plots import save_animation, save_rollout_animation
from runout.scene import Material
from runout.trajectory import Trajectory


def _falling(frames: int = 10) -> Trajectory:
    xy = np.tile(np.array([[1.0, 5.0], [3.0, 5.0], [5.0, 1.0]], dtype=np.float32), (frames, 1, 1))
    xy[:, :2, 1] -= np.linspace(0, 3, frames)[:, None]
    return Trajectory(xy, np.array([6, 6, 3]), np.zeros(3, dtype=np.int64), [Material("sand")], 0.0375,
                      np.array([[0.0, 10.0], [0.0, 10.0]]))


def test_importing_the_plots_leaves_the_backend_to_the_caller():
    code = "import sys, runout.plots; assert 'matplotlib.pyplot' not in sys.modules"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def test_both_animations_write_every_chosen_frame(tmp_path):
    traj = _falling()
    stacked = save_animation([traj, traj], tmp_path / "stacked.gif", stride=3)
    assert Image.open(stacked).n_frames == 4  # frames 0, 3, 6 and the last
    side = save_rollout_animation(traj, traj, tmp_path / "animation", max_frames=5)
    assert side.suffix in (".gif", ".mp4") and side.is_file()


def _coloured_share(image: Image.Image) -> float:
    """Share of the pixels that are coloured (not white, grey or black): the drawn soil points."""
    rgb = np.asarray(image.convert("RGB")).astype(int)
    return float(((rgb.max(axis=2) - rgb.min(axis=2)) > 30).mean())


def test_every_frame_of_an_animation_shows_its_points(tmp_path):
    """Each frame is drawn into a cleared axes; the points' size must not shrink to nothing
    after the first (it did: every later frame of the demo's animation was empty)."""
    xy = np.stack(np.meshgrid(np.arange(300.0, 700.0, 4.0), np.arange(2.0, 100.0, 4.0)), -1).reshape(-1, 2)
    positions = np.repeat(xy[None].astype(np.float32), 12, axis=0)
    positions[:, :, 0] += np.linspace(0, 50, 12)[:, None]  # the block slides right
    n = len(xy)
    traj = Trajectory(positions, np.full(n, 6), np.zeros(n, dtype=np.int64), [Material("sand")], 0.0375,
                      np.array([[0.0, 1000.0], [0.0, 200.0]]))
    gif = Image.open(save_animation([traj, traj], tmp_path / "slide.gif", stride=4))
    shares = []
    for k in range(gif.n_frames):
        gif.seek(k)
        shares.append(_coloured_share(gif))
    assert gif.n_frames == 4 and min(shares) > 0.5 * shares[0] > 0, shares
