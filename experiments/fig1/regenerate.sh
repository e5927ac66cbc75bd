#!/usr/bin/env bash
# Every table and figure of Figure 1 on Brax's variants regenerated from the committed runs by gsa_jax.plot (the
# verdicts judged as gsa_jax.answer's first look; Brax's tasks have no MuJoCo C version, so the random return of
# random_returns.json is taken as exact and the scores are the training-time deterministic evaluations). Run from
# the repository root:  bash experiments/fig1/regenerate.sh
set -euo pipefail
py=.venv/bin/python
r=experiments/fig1/results
for t in inverted_double_pendulum hopper walker2d; do $py -m gsa_jax.plot $r/fig1_$t; done
for t in halfcheetah ant; do $py -m gsa_jax.plot $r/fig1_${t}_seeds_0_4 $r/fig1_${t}_seeds_5_9 --out $r/fig1_$t; done
$py -m gsa_jax.plot $r/fig1_inverted_double_pendulum $r/fig1_hopper $r/fig1_walker2d $r/fig1_halfcheetah_seeds_0_4 \
  $r/fig1_halfcheetah_seeds_5_9 $r/fig1_ant_seeds_0_4 $r/fig1_ant_seeds_5_9 --out $r/merged
$py -m gsa_jax.plot $r/fig1_hopper $r/fig1_walker2d --out $r/hopper_walker2d
