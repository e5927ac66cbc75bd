"""Running training: experiment specs, compiled programs, the chunk loop, stores and checkpoints, worker
processes; one run and a sweep's groups. Imports gsa_jax.algorithm only."""
