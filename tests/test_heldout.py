"""The held-out score that judges pilots and chunks: a perfect prediction scores 0 and
standing still scores each travelling front as its whole travel."""

import numpy as np
import pytest

from runout.evaluate.heldout import score, standing_still
from runout.trajectory import trajectory_from_features
from test_gns_synthetic import BOUNDS, FRAME_DT, falling_block


def truth():
    return trajectory_from_features(*falling_block(30, 0.2), FRAME_DT, BOUNDS)


def test_the_truth_scores_zero_and_standing_still_scores_the_whole_travel():
    t = truth()
    perfect = score([t], [t], spacing=0.5)
    assert perfect["position_error_m"] == 0.0 and perfect["front_error"] == 0.0 and perfect["runout_error"] == 0.0
    still = score([standing_still(t)], [t], spacing=0.5)
    assert still["fronts_scored"] == 2 and still["front_error"] == pytest.approx(1.0)
    assert still["displacement_m"] == 0.0 and still["displacement_mpm_m"] > 2.0  # the block falls about 3 m
    soil = t.soil
    expected = np.linalg.norm(t.positions[:, soil] - t.positions[:1, soil], axis=-1).mean()
    assert still["position_error_m"] == pytest.approx(expected, rel=1e-6)


def test_fronts_that_barely_move_are_not_scored():
    t = truth()
    assert score([standing_still(t)], [t], spacing=10.0)["fronts_scored"] == 0  # the sides spread < 10 m
