"""A sweep worker that stalls once, like an XLA:CPU hang (alive, no progress), for the watchdog test:

    python tests/hang_worker.py N MARKER JOB      (JOB: a sweep worker's job, gsa_jax.orchestration.sweep_job)

After its N-th chunk it sleeps forever, unless MARKER exists (it creates MARKER first, so the
restarted worker runs through). supervise_stalling_worker runs one under the watchdog, as the tests do."""

import os
import sys
import time

from gsa_jax.orchestration import sweep_job


def supervise_stalling_worker(hang_after, marker, spec_file, out):
    """One such worker training spec_file into out (an existing folder), under gsa_jax.running.supervise's watchdog
    (8 s without progress, at most 2 restarts) -> (supervise's exit code, the watchdog's log lines)."""
    from gsa_jax.running.spec import load_spec
    from gsa_jax.running.supervise import supervise

    lines = []
    job = sweep_job.SweepJob(load_spec(str(spec_file)), str(out), worker=True, quiet=True)
    cmd = [sys.executable, os.path.abspath(__file__), str(hang_after), str(marker), sweep_job.job_to_json(job)]
    return supervise([cmd], [str(out)], watchdog_min_s=8, max_restarts=2, log=lines.append), lines


def main():
    hang_after, marker, argv = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
    chunks = [0]

    def after_chunk():
        chunks[0] += 1
        if chunks[0] == hang_after and not os.path.exists(marker):
            open(marker, "w").close()
            time.sleep(1e9)

    return sweep_job.main(argv, after_chunk=after_chunk)


if __name__ == "__main__":
    sys.exit(main())
