"""The start states a controller is scored from, named once for every command (no JAX, no MuJoCo imported).

Episode i of a start set begins from the task's start law drawn with seed FIRST + i (TaskRecord.reset(seed), in
MuJoCo C), so anyone re-running a controller from the same seeds gets the same return.

- The selection starts (SELECTION_SEED + i, SELECTION_EPISODES of them): `gsa score`'s controller_score, the one
  every verdict and the answer's choice of its best seed use; `gsa deploy` without seed options. `gsa verify`'s
  nominal episodes (50; 16 with --quick) and `gsa robustness`'s (20) begin at the same seed.
- The fresh starts (FRESH_SEED + i, FRESH_EPISODES of them): an answer's chosen controller re-scored on starts it was
  not picked on (`gsa deploy --start-seed 20000 --episodes 100` gives the same number).

Training's own evaluations draw their starts from JAX keys (`gsa train --eval-seed`), none of these.
"""

SELECTION_SEED = 10_000
SELECTION_EPISODES = 10  # the episode noise of their mean is small beside the spread over training seeds
FRESH_SEED = 20_000
FRESH_EPISODES = 100  # the constructive answer's least: its exhibited controllers are compared on these

NAMES = {(SELECTION_SEED, SELECTION_EPISODES): "the selection starts", (FRESH_SEED, FRESH_EPISODES): "the fresh starts"}


def describe(first: int, episodes: int) -> str:
    """'the selection starts (seeds 10000-10009)': a start set in words, for reports and printed lines (named where it
    is one of the two, else 'the starts')."""
    name = NAMES.get((int(first), int(episodes)), "the starts")
    return f"{name} (seeds {first}-{first + episodes - 1})" if episodes > 1 else f"{name} (seed {first})"
