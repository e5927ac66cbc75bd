"""Trained controllers outside training: inspection, export (npz, ONNX, C), evaluation in MuJoCo C and
gymnasium, shifted physics, rendering. Imports gsa_jax.algorithm and gsa_jax.running."""
