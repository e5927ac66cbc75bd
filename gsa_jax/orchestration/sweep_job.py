"""A sweep as a job: the checked settings of one sweep (SweepJob), trained in this process or by supervised worker
processes, each of which runs `python -m gsa_jax.orchestration.sweep_job JOB` (JOB: the worker's SweepJob as JSON).
`gsa sweep` builds the job from its command line; `gsa answer` starts one per class sweep with the same entry. Exit
statuses are `gsa sweep`'s: 0 done (or stopped as asked), 1 some runs failed (NaN/inf), 2 bad input or a locked /
changed / unreadable output directory, 3 a worker hung repeatedly, 4 disk full, 130 interrupted."""

import json
import os
import sys
from typing import Callable, NamedTuple

from gsa_jax.errors import disk_full, run_command
from gsa_jax.running.checkpoint import CheckpointError, DiskFullError, write_atomic
from gsa_jax.running.runinfo import resume_command
from gsa_jax.running.runlock import hold
from gsa_jax.running.spec import RUN_BATCH, SpecError, SweepSpec, build_grid, check_spec
from gsa_jax.running.supervise import heartbeat_writer, supervise

ENTRY = "gsa_jax.orchestration.sweep_job"  # `python -m` of a job's process
MAX_ARGUMENT = 64 * 1024  # characters of a job passed on the command line (Linux allows 128 KiB in one argument)


class SweepJob(NamedTuple):
    """One sweep's settings (gsa sweep's options, checked). local: worker processes on this machine; watchdog: run
    under the restarting supervisor (False: in this process); worker: this process trains its share, supervised by
    another; devices: shard over the first N local devices (None: all); the rest as gsa sweep --help says."""

    spec: SweepSpec
    out: str
    local: int = 1
    watchdog: bool = True
    worker: bool = False
    devices: int | None = None
    coordinator: str | None = None
    num_processes: int = 1
    process_id: int = 0
    run_batch: int = RUN_BATCH
    runs_per_program: int = 0
    force: bool = False
    tensorboard: bool = True
    quiet: bool = False
    stop_after_chunks: int | None = None
    watchdog_min: float = 600.0
    max_restarts: int = 5


def job_to_json(job: SweepJob) -> str:
    """The job as one JSON text (its spec as sweep.json stores it): a worker process's argument."""
    return json.dumps({**job._asdict(), "spec": job.spec.to_json()})


def job_from_json(text: str) -> SweepJob:
    """job_to_json's inverse (the spec checked again; '@PATH': the text in the file PATH); SpecError for a text that
    is not one."""
    try:
        if text.startswith("@"):
            with open(text[1:]) as f:
                text = f.read()
        fields = json.loads(text)
        return SweepJob(**{**fields, "spec": check_spec(fields["spec"], source="the sweep job")})
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SpecError(f"not a sweep job ({type(e).__name__}: {e})") from None


def job_command(job: SweepJob) -> list:
    """The command line of a process that runs `job` (python -m gsa_jax.orchestration.sweep_job JOB): the job's
    JSON text, or where it is longer than a command line's argument may be (a large tuning grid), '@' and the
    file DIR/job-<process>.json it is written to (DIR: the job's worker directory)."""
    text = job_to_json(job)
    if len(text) > MAX_ARGUMENT:
        os.makedirs(worker_dir(job), exist_ok=True)
        path = os.path.join(worker_dir(job), f"job-{job.process_id}.json")
        write_atomic(path, text)
        text = "@" + os.path.abspath(path)
    return [sys.executable, "-m", ENTRY, text]


def worker_dir(job: SweepJob) -> str:
    """Where this process's share of the sweep is written (OUT, or OUT/process-<i> of a multi-process sweep)."""
    return job.out if job.num_processes == 1 else os.path.join(job.out, f"process-{job.process_id}")


def run_job(job: SweepJob, after_chunk: Callable | None = None) -> int:
    """Train the sweep: this process's share (a worker, or no watchdog) or its supervised workers, under the output
    directory's lock. after_chunk: see run_worker. Returns the exit status."""
    if job.worker:
        return run_worker(job, after_chunk)
    from gsa_jax.running.sweeps import SweepOptions, check_resumable, spec_tasks

    lock_dir = worker_dir(job)
    try:
        os.makedirs(lock_dir, exist_ok=True)
    except OSError as e:
        raise SpecError(f"--out {job.out!r} cannot be created: {e.strerror or e}") from None
    with hold(lock_dir, f"gsa_jax.sweep {job.spec.name}", log=lambda m: print(m, file=sys.stderr)):
        if job.local > 1 or job.watchdog:  # every worker finds what process 0 would refuse: refused before them
            check_resumable(job.out, job.spec, spec_tasks(job.spec, build_grid(job.spec))[1],
                            SweepOptions(force=job.force, runs_per_program=job.runs_per_program))
            return supervise_workers(job)
        return run_worker(job, after_chunk)


def worker_jobs(job: SweepJob) -> list:
    """The jobs of the worker processes: one per local process (each its own process-<i>), or this process's share
    of a multi-process sweep."""
    if job.local > 1:
        return [job._replace(worker=True, process_id=i, num_processes=job.local, local=1) for i in range(job.local)]
    return [job._replace(worker=True)]


def supervise_workers(job: SweepJob) -> int:
    """Start the worker processes under the watchdog; then collect failed runs into sweep.json."""
    from gsa_jax.running.sweeps import EXIT_FAILED_RUNS

    jobs = worker_jobs(job)
    if job.local > 1:
        print(f"sweep: {job.local} local worker processes (one XLA CPU device each); logs prefixed [process i]", flush=True)
    dirs = [worker_dir(j) for j in jobs]
    for d in dirs:
        os.makedirs(d, exist_ok=True)
    status = supervise([job_command(j) for j in jobs], dirs, job.watchdog_min, job.max_restarts)
    if status == 0:
        if failed_runs_reported(job.out, dirs):
            return EXIT_FAILED_RUNS
        print(f"sweep complete: {job.out}", flush=True)
    return status


def failed_runs_reported(out: str, dirs: list, log: Callable = print) -> list:
    """The runs that failed (NaN/inf) in dirs, written into out/sweep.json and summarized by log
    (running.sweeps.report_failures); a full disk there is one line naming what is intact (training is done)."""
    from gsa_jax.running.sweeps import report_failures

    try:
        return report_failures(out, dirs, log=log)
    except DiskFullError as e:
        raise disk_full(e, "the final one of every group (training is done; only sweep.json is behind)") from None


def worker_devices(job: SweepJob) -> tuple:
    """The devices this process trains on (the first job.devices local ones); joins a multi-process sweep first."""
    import jax

    if job.num_processes > 1 and job.coordinator:
        jax.distributed.initialize(job.coordinator, job.num_processes, job.process_id)
        # eager arrays (the MJX model Brax builds) would otherwise land on global device 0, which
        # belongs to process 0; each process works on its own devices only
        jax.config.update("jax_default_device", jax.local_devices()[0])
    devices = jax.local_devices()
    if job.devices is not None:
        if not 1 <= job.devices <= len(devices):
            raise SpecError(f"--devices must be in 1..{len(devices)}")
        devices = devices[: job.devices]
    return tuple(devices)


def run_worker(job: SweepJob, after_chunk: Callable | None = None) -> int:
    """Train this process's share in this process (a supervised worker, or no watchdog). after_chunk: called after
    every chunk's heartbeat (tests inject faults with it)."""
    from gsa_jax.running.sweeps import EXIT_FAILED_RUNS, SweepOptions, run_sweep

    devices, wdir = worker_devices(job), worker_dir(job)
    os.makedirs(wdir, exist_ok=True)
    beat = heartbeat_writer(wdir)

    def heartbeat(duration):
        beat(duration)
        if after_chunk:
            after_chunk()

    try:
        options = SweepOptions(devices, job.quiet, job.stop_after_chunks, job.process_id, job.num_processes,
                               heartbeat, job.run_batch, local_workers=job.coordinator is None, force=job.force,
                               tensorboard=job.tensorboard, runs_per_program=job.runs_per_program)
        complete = run_sweep(job.spec, job.out, options)
    except CheckpointError as e:
        raise CheckpointError(f"{e} (a sweep resumes with the same --devices as the interrupted one)") from None
    except DiskFullError as e:
        raise disk_full(e, getattr(e, "last_intact", "none (nothing trained yet)")) from None
    if not job.quiet:
        again = "" if job.coordinator else f" or: {resume_command('sweep', '--resume', job.out)}"
        done_msg = f"done: {job.out}" if complete else f"stopped: {job.out}; continue with the same command{again}"
        print((f"[process {job.process_id}] " if job.num_processes > 1 else "sweep ") + done_msg, flush=True)
    if job.worker or job.num_processes > 1:
        return 0
    return EXIT_FAILED_RUNS if failed_runs_reported(job.out, [wdir], log=print) else 0


def main(argv: "list | None" = None, after_chunk: Callable | None = None) -> int:
    """`python -m gsa_jax.orchestration.sweep_job JOB`: run the job (a worker's, or a whole supervised sweep's)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) != 1:
        print(f"usage: python -m {ENTRY} JOB (a sweep job as JSON; gsa sweep starts these)", file=sys.stderr)
        return 2
    return run_command("sweep", lambda: run_job(job_from_json(argv[0]), after_chunk))


if __name__ == "__main__":
    sys.exit(main())
