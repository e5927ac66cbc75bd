"""The names of what a training run measures, defined once (no JAX import: the plotting tools read them).

ITERATION_METRICS: what the compiled program returns for every PPO iteration (gsa_jax.algorithm.ppo), in the
column order of the tidy tables. A single run's metrics.csv adds the deterministic evaluation and
the wall clock (RUN_COLUMNS); a sweep's tidy metrics.csv has TIDY_METRICS after its run columns.
"""

ITERATION_METRICS = (
    "iteration", "env_steps", "episode_return", "episodes", "epsilon", "sigma_min", "lr", "policy_loss",
    "value_loss", "approx_kl", "clip_fraction", "grad_norm", "partition_entropy", "clusters_used",
)
# eval_return: the deterministic controller's mean return over its evaluation episodes, where evaluated;
# eval_failures: how many of those episodes failed (non-finite reward or observation: gsa_jax.algorithm.episodes).
EVAL_METRICS = ("eval_return", "eval_failures")
TIDY_METRICS = ITERATION_METRICS[:3] + EVAL_METRICS + ITERATION_METRICS[3:]  # a sweep's tidy metrics.csv
RUN_COLUMNS = TIDY_METRICS + ("wall_s",)  # a single run's metrics.csv
EVALUATIONS_PER_RUN = 25  # default number of deterministic evaluations in a run (eval_every = iterations // 25)
FINAL_EVALUATIONS = 3  # a run's final score: the mean deterministic return of its last 3 scheduled evaluations
INTEGER_METRICS = ("iteration", "env_steps", "eval_failures", "clusters_used")  # written as integers in the tables
