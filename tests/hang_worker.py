"""A sweep worker that stalls once, like an XLA:CPU hang (alive, no progress), for the watchdog test:

    python tests/hang_worker.py N MARKER <gsa_jax.sweep arguments ... --worker>

After its N-th chunk it sleeps forever, unless MARKER exists (it creates MARKER first, so the
restarted worker runs through)."""

import os
import sys
import time

from gsa_jax import sweep


def main():
    hang_after, marker, argv = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
    chunks = [0]

    def after_chunk():
        chunks[0] += 1
        if chunks[0] == hang_after and not os.path.exists(marker):
            open(marker, "w").close()
            time.sleep(1e9)

    return sweep.main(argv, after_chunk=after_chunk)


if __name__ == "__main__":
    sys.exit(main())
