"""Graph Network Simulator: a learned, differentiable surrogate of the MPM.

What every learned engine shares (the window, the material codec, radius per spacing) is
runout.contract; what only the GNS reads is here. The package imports nothing itself; import
from the modules:

    runout.gns.schema       FeatureSchema, NetworkConfig, MAX_STEPS (torch-free)
    runout.gns.graph        radius neighbours (cell lists, no cap)
    runout.gns.network      encode-process-decode (no metres, no walls)
    runout.gns.features     Constraints (walls, ground, kinematic points), Ground, overburden_depth
    runout.gns.simulator    GraphNetworkSimulator (normalisation, features, update), Normalisation
    runout.gns.training     random-walk noise, corrected target, masked loss, pushforward
    runout.gns.windows      TrainingWindows (a split's training windows), TrainingBatch, mirrored
    runout.gns.rollout      rollout(...), rollout_trajectory(...), start_window(...)
    runout.gns.checkpoint   load_simulator(path, device="cpu"), save_checkpoint, read_checkpoint
    runout.gns.checkpoint_checks  every entry of a checkpoint, resumability, schema against data
    runout.gns.fine_tuning  widen_material_features, renormalise, restride (--init)
    runout.gns.engine       GnsEngine: the GNS behind the learned-engine contract (runout.learned)

Commands reach the GNS only through runout.learned.load.load_engine, which reads the engine
a checkpoint holds; what every learned engine shares (scenes at the model's spacing, the
training ranges, safe checkpoint reading, the codec as tensors) is runout.learned. No module
here imports another engine.
"""
