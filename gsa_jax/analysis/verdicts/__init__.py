"""Is K enough? The verdict at a margin (Yuen's trimmed-mean t), the sequential design and Holm's shares, the
baseline's adequacy, a fixed grid's verdicts, and the answer's decisions with its report (the loop that trains the
answer's rounds: gsa_jax.orchestration.answer_loop)."""
