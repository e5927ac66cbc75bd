#!/usr/bin/env bash
# Every committed controller of Figure 1 on v5 and the atlas re-run in MuJoCo C from fixed start states (gsa_jax.score,
# controller_scores.csv), then every table regenerated from those scores with the verdicts (gsa_jax.plot: the random
# policy measured over 128 episodes in MuJoCo C into random_policy.json, each table judged as gsa_jax.answer's first
# look against a baseline shown adequate), the atlas table, the re-judged answers and the chosen controllers on fresh
# starts; the committed answers judged anew on their runs (regenerate_answers.py). Run from the repository root:  bash experiments/verdicts/regenerate.sh
set -euo pipefail
py=.venv/bin/python
v5=experiments/fig1_v5/results
checks=experiments/atlas_dmc/checks/results/quadruped-walk_mixture_figure1_settings
$py -m gsa_jax.score experiments/atlas_dmc/results $v5 $checks experiments/tuning/results/*/flat_ppo/evaluation
$py experiments/verdicts/tuned_references.py
for d in experiments/atlas_dmc/results/*/; do
  if [ -d "$d/flat_ppo" ]; then $py -m gsa_jax.plot "$d/flat_ppo" "$d/mixture" --out "$d"; fi
done
for t in InvertedDoublePendulum-v5 Hopper-v5 HalfCheetah-v5; do $py -m gsa_jax.plot $v5/fig1_v5_$t; done
for t in Walker2d-v5 Ant-v5; do $py -m gsa_jax.plot $v5/fig1_v5_${t}_seeds_0_4 $v5/fig1_v5_${t}_seeds_5_9 --out $v5/fig1_v5_$t; done
$py -m gsa_jax.plot $v5/fig1_v5_InvertedDoublePendulum-v5 $v5/fig1_v5_Hopper-v5 $v5/fig1_v5_HalfCheetah-v5 \
  $v5/fig1_v5_Walker2d-v5_seeds_0_4 $v5/fig1_v5_Walker2d-v5_seeds_5_9 $v5/fig1_v5_Ant-v5_seeds_0_4 $v5/fig1_v5_Ant-v5_seeds_5_9 \
  --out $v5/merged
$py -m gsa_jax.plot experiments/atlas_dmc/results/quadruped-walk/flat_ppo $checks/mixture --out $checks
$py experiments/atlas_dmc/atlas.py > /dev/null
$py experiments/verdicts/regenerate_answers.py
$py experiments/verdicts/rejudge.py
$py experiments/verdicts/fresh_scores.py
$py experiments/verdicts/answer_speed.py
