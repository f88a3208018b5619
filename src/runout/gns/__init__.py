"""Graph Network Simulator: a learned, differentiable surrogate of the MPM.

Public API:
    load_simulator(path, device="cpu") -> Simulator        (eval mode; InputError if bad)
    rollout(simulator, initial_positions, particle_type, material, n_steps, bounds,
            checkpoint=False, progress=False, stop_speed=None) -> Tensor [6 + n, N, 2]
    rollout_trajectory(simulator, initial: Trajectory, n_frames, stop_speed=0.05) -> Trajectory
    scene_at_rest(scene) -> Trajectory                        (6 identical frames)
"""

from runout.gns.checkpoint import load_simulator, save_checkpoint
from runout.gns.rollout import RolloutDiverged, rollout, rollout_trajectory, scene_at_rest
from runout.gns.schema import FeatureSchema
from runout.gns.simulator import NetworkConfig, Normalisation, Simulator

__all__ = [
    "FeatureSchema", "NetworkConfig", "Normalisation", "RolloutDiverged", "Simulator",
    "load_simulator", "rollout", "rollout_trajectory", "save_checkpoint", "scene_at_rest",
]
