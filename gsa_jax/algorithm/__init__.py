"""The algorithm: networks, optimizer, normalizer, policies (mixture of linear controllers, MLP), the
Retrace critic and PPO. Pure JAX functions; imports nothing else from gsa_jax."""
