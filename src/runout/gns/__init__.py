"""Graph Network Simulator: a learned, differentiable surrogate of the MPM.

The package imports nothing itself, so that runout.gns.schema (the GNS contract: feature
layout, material codec, history, radius per spacing) is read by the scene and file layers
without the network. Import from the modules:

    runout.gns.schema      FeatureSchema, encode_material / decode_material, HISTORY, RADIUS_PER_SPACING
    runout.gns.simulator   Simulator, NetworkConfig, Normalisation
    runout.gns.checkpoint  load_simulator(path, device="cpu"), save_checkpoint
    runout.gns.rollout     rollout(...), rollout_trajectory(...), scene_at_rest(scene), RolloutDiverged
"""
