"""The commands of `gsa` (gsa_jax.cli), one module each: its options, its body and its `main(argv) -> exit status`."""
