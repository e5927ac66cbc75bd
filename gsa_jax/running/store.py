"""What the stores of a single run (gsa_jax.running.single.RunStore) and of a sweep group (gsa_jax.running.sweeps.GroupStore)
share: their directory, the resume check (a checkpoint exists), TensorBoard event files that restart from the
checkpoint and follow every save, and the one warning path for what a user must see even with --quiet.
Each store keeps its own file layout (the run's metrics.csv is its table; a group's metrics.npz holds every
run's arrays); both are driver stores (gsa_jax.running.driver: load, save, finish)."""

import os
import sys

from gsa_jax.running.tensorboard import Board, follow

STATE_FILES = ("state.npz", "state.prev.npz")


def warn(msg):
    """A line the user must see even with --quiet (stderr)."""
    print(msg, file=sys.stderr, flush=True)


class Store:
    """A driver store's shared part: `root` holds the checkpoint; board_dir/<label> the event files of each
    run (labels: the runs' names; [""] for a single run: board_dir itself; board_dir None: no event files)."""

    def __init__(self, root, board_dir, labels):
        self.root = root
        self.board = Board(board_dir, labels) if board_dir else None

    def path(self, name):
        return os.path.join(self.root, name)

    def has_checkpoint(self):
        return any(os.path.exists(self.path(n)) for n in STATE_FILES)

    def load(self, template):
        """(state, metrics [R, done], done) of the checkpoint in root, or None if there is nothing to resume;
        the event files restart from it."""
        return follow(self.board, self.load_checkpoint(template) if self.has_checkpoint() else None)

    def load_checkpoint(self, template):
        raise NotImplementedError

    def follow_save(self, metrics, done):
        """The event files after a save: the iterations since the last one."""
        if self.board:
            self.board.append(metrics, done)
