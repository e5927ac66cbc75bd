"""The columns of the tables gsa_jax.plot writes (final_returns.csv, per_run_scores.csv, aggregate.csv), declared
once: tables writes them; figures, quote, published and the verdicts read them by these names (CONTROLLER_SCORE is
also controller_scores.csv's column and the metric a verdict names). A group holds a statistic and its interval in the
order the file holds them."""

from gsa_jax.analysis.sweeps.stats import LAST_EPISODES

K_OVER_ACTION_DIM = "K_over_action_dim"
SEEDS = "seeds"
SCORE_KIND = "score"  # which score the statistics use: controller, deterministic or training
MEAN_CI = ("final_return_mean", "ci95_halfwidth")  # mean and 95% t half-width of the cell's final scores
IQM_CI = ("iqm", "iqm_ci_low", "iqm_ci_high")
P_FLAT_CI = ("p_better_than_flat_ppo", "p_ci_low", "p_ci_high")
P_GAE_CI = ("p_better_than_gae", "p_gae_ci_low", "p_gae_ci_high")
TRAINING_CI = ("training_return_mean", "training_ci95_halfwidth")
CURVE_CI = ("curve_iqm", "curve_ci_low", "curve_ci_high")  # the IQM of the learning curves' means
NORMALIZED_IQM_CI = ("normalized_iqm", "iqm_ci_low", "iqm_ci_high")  # aggregate.csv
CONTROLLER_SCORE = "controller_score"  # per_run_scores.csv: the committed controller re-run in MuJoCo C
FINAL_SCORE = "final_score"  # per_run_scores.csv: the mean of its last scheduled evaluations
LAST_EPISODES_RETURN = f"training_return_last_{LAST_EPISODES}_episodes"  # per_run_scores.csv: CleanRL's score
