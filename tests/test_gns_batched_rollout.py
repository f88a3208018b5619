"""Several scenes rolled out in one graph batch (runout.gns.rollout.rollout_trajectories) give
each scene the trajectory it gets alone: no edge joins two scenes, and each keeps its own
domain walls and materials."""

import numpy as np
import pytest
import torch

from runout.errors import InputError
from runout.gns.rollout import rollout_trajectories, rollout_trajectory
from runout.gns.schema import FeatureSchema
from runout.gns.schema import NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.trajectory import trajectory_from_features
from test_gns_synthetic import FRAME_DT, falling_block

torch.set_num_threads(1)

STATS = Normalisation((0.0, -0.01), (0.02, 0.03), (0.0, -1e-3), (2e-3, 3e-3), 2.5e-3)


def model() -> GraphNetworkSimulator:
    torch.manual_seed(3)
    return GraphNetworkSimulator(FeatureSchema(material_features=("tan_phi", "c_over_100kPa")), STATS, 4.6,
                     NetworkConfig(16, 16, 2, 2)).eval()


def scenes():
    """Three blocks on the same spot (they would touch if batched wrongly): other materials,
    and the third in a domain whose right wall cuts through the block."""
    a = trajectory_from_features(*falling_block(12, 0.2), FRAME_DT, [[0.0, 60.0], [0.0, 30.0]])
    b = trajectory_from_features(*falling_block(12, 0.7, cohesion=0.5), FRAME_DT, [[0.0, 60.0], [0.0, 30.0]])
    c = trajectory_from_features(*falling_block(12, 0.4, columns=8), FRAME_DT, [[5.0, 29.0], [1.0, 25.0]])
    return [a, b, c]


def test_a_batch_of_scenes_rolls_out_as_each_scene_alone():
    simulator, truths = model(), scenes()
    together = rollout_trajectories(simulator, truths, 40, stop_speed=None)
    for truth, batched in zip(truths, together):
        alone = rollout_trajectory(simulator, truth, 40, stop_speed=None)
        assert batched.positions.shape == alone.positions.shape == (40, truth.n_points, 2)
        assert np.abs(batched.positions - alone.positions).max() < 1e-5  # m (equal here; summation order may differ)
        assert np.abs(alone.positions[-1] - alone.positions[0]).max() > 0.05  # the model moves the points
        assert batched.name == truth.name and np.array_equal(batched.bounds, truth.bounds)
    soil = together[2].positions[1:, together[2].particle_type != 3]  # after the first step (frame 0 is given)
    assert soil[..., 0].max() <= 29.0 and soil[..., 1].min() >= 1.0  # clamped into its own domain


def test_scenes_of_other_frame_steps_are_refused():
    a, b, _ = scenes()
    b = trajectory_from_features(b.positions, b.particle_type, b.material_features(2), 2 * FRAME_DT, b.bounds)
    with pytest.raises(InputError, match="one frame time step"):
        rollout_trajectories(model(), [a, b], 10)
