"""Training the learned engines: `trainer`, the one loop every engine's training task runs in
(stop conditions, hooks, checkpoints, progress), and `engines`, what `runout train` calls for
each engine."""
