"""What every learned engine shares: the contract commands are written against (engine), the
loader that reads the engine from its checkpoint (load), the scene as an engine starts it
(scenes), its training ranges (training_range) and safe checkpoint reading (files). The
engines themselves live in runout.gns and runout.neural_mpm; nothing here is of one engine."""
