"""gsa_jax: generalized state abstraction (mixtures of linear-Gaussian controllers) trained by PPO in pure JAX."""

__version__ = "0.1.0"
