"""Graph Network Simulator: a learned, differentiable surrogate of the MPM.

The GNS contract (feature layout, material codec, history, radius per spacing) is
runout.contract, below the scene and file layers and torch-free. The package imports nothing
itself; import from the modules:

    runout.gns.schema      the contract's names for the GNS, encode_materials_torch (differentiable codec)
    runout.gns.simulator   GraphNetworkSimulator, NetworkConfig, Normalisation
    runout.gns.checkpoint  load_simulator(path, device="cpu"), save_checkpoint
    runout.gns.rollout     rollout(...), rollout_trajectory(...), start_window(...)
    runout.gns.engine      GnsEngine: the GNS behind the learned-engine contract (runout.learned)

Commands reach the GNS only through runout.learned.load.load_engine, which reads the engine
a checkpoint holds; what every learned engine shares (scenes at the model's spacing, the
training ranges, safe checkpoint reading) is runout.learned.
"""
