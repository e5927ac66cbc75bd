"""The vmapped seed benchmark's measurements, workers and figure (`python -m gsa_jax.bench`)."""
