"""Graph Network Simulator: a learned, differentiable surrogate of the MPM.

The GNS contract (feature layout, material codec, history, radius per spacing) is
runout.contract, below the scene and file layers and torch-free. The package imports nothing
itself; import from the modules:

    runout.gns.schema      the contract's names for the GNS, encode_materials_torch (differentiable codec)
    runout.gns.simulator   Simulator, NetworkConfig, Normalisation
    runout.gns.checkpoint  load_simulator(path, device="cpu"), save_checkpoint
    runout.gns.rollout     rollout(...), rollout_trajectory(...), scene_at_rest(scene), RolloutDiverged
"""
