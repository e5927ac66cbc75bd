"""Fault injection for `python -m gsa_jax.train` and the shared pieces (validation, checkpoints, locks):
full disks at every write, unreadable checkpoints, bad values, a second writer. Sweeps: tests/test_sweep.py."""

import errno
import json
import os

import numpy as np
import pytest
from test_train_command import SMALL, read_csv, strip_wall

from gsa_jax.running import checkpoint
from gsa_jax.train import main


class DiskFull:
    """Make the n-th write of a file named `name` (its .tmp) fail with ENOSPC, once."""

    def __init__(self, monkeypatch, name, n):
        self.name, self.n, self.seen, self.fired = name, n, 0, False
        real = checkpoint._write_file

        def write(path, data, mode):
            if os.path.basename(path) == name + ".tmp" and not self.fired:
                self.seen += 1
                if self.seen == n:
                    self.fired = True
                    raise OSError(errno.ENOSPC, "No space left on device")
            return real(path, data, mode)

        monkeypatch.setattr(checkpoint, "_write_file", write)


def no_temp_files(directory):
    return [f for root, _, files in os.walk(directory) for f in files if f.endswith(".tmp")]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("faults") / "ref"
    assert main(SMALL + ["--out", str(out)]) == 0
    return out


def assert_same_run(out, ref):
    assert strip_wall(read_csv(out / "metrics.csv")) == strip_wall(read_csv(ref / "metrics.csv"))
    with np.load(out / "params.npz") as a, np.load(ref / "params.npz") as b:
        for k in a.files:
            if not k.startswith("meta/"):
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)


# (file, which of its writes in that invocation fails), in order, each invocation resuming the last
# (SMALL: 4 chunks of 1 iteration). First writes: runs.csv and config.json at the start, then after chunk 1
# metrics.npz, params.npz, metrics.csv and state.npz (the checkpoint; nothing saved yet: each starts
# afresh). Then mid-run: metrics.npz at chunk 2, params.npz at chunk 3, state.npz at chunk 4; at the end
# failed.json, config.json (the result) and DONE, the state kept until DONE is written.
DISK_FULL_CASES = [("runs.csv", 1), ("config.json", 1), ("metrics.npz", 1), ("params.npz", 1), ("metrics.csv", 1),
                   ("state.npz", 1), ("metrics.npz", 2), ("params.npz", 2), ("state.npz", 2), ("failed.json", 1),
                   ("config.json", 2), ("DONE", 1)]
INTACT_AFTER = [0, 0, 0, 0, 0, 0, 1, 2, 3, 4, 4, 4]


def test_disk_full_at_every_write_then_resume_equals_uninterrupted(reference, tmp_path, monkeypatch, capsys):
    """Each write path fails once with ENOSPC (first write, and mid-run): one line naming the directory,
    the space needed and the last intact iteration, exit 4, no temp file; the next --resume continues.
    After all of them the run equals an uninterrupted one."""
    out = tmp_path / "full"
    for i, (name, n) in enumerate(DISK_FULL_CASES):
        with monkeypatch.context() as m:
            inj = DiskFull(m, name, n)
            # --resume where the first writes failed (no run saved yet) names the task, as a resumable first run does
            status = main(SMALL + ["--out", str(out)] + (["--resume", "--env", "inverted_double_pendulum"] if i else []))
        err = capsys.readouterr().err.strip()
        assert inj.fired and status == 4, (name, n, status, err)
        line = err.splitlines()[-1]
        assert line.startswith("gsa train: error: disk full: writing ") and str(out) in line, line
        assert "MiB more free space" in line and f"the last intact checkpoint is iteration {INTACT_AFTER[i]};" in line
        assert no_temp_files(out) == []
    assert main(SMALL + ["--out", str(out), "--resume"]) == 0
    assert_same_run(out, reference)
    assert json.loads((out / "config.json").read_text())["result"]["status"] == "finished"


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_unreadable_state_falls_back_to_previous(reference, tmp_path, capsys, damage):
    """A truncated or garbage state.npz: one line says which file and which checkpoint is used, the run
    resumes from state.prev.npz and ends identical to an uninterrupted run."""
    out = tmp_path / damage
    assert main(SMALL + ["--out", str(out), "--stop-after", "3"]) == 0
    assert (out / "state.prev.npz").exists() and (out / "metrics.prev.npz").exists()
    state = out / "state.npz"
    data = state.read_bytes()
    state.write_bytes(data[: len(data) // 2] if damage == "truncate" else b"not a zip file" * 100)
    capsys.readouterr()
    assert main(SMALL[:-1] + ["--out", str(out), "--resume"]) == 0
    text = capsys.readouterr()
    warning = [line for line in text.out.splitlines() + text.err.splitlines() if "state.npz is unreadable" in line]
    assert len(warning) == 1 and "resuming from the previous checkpoint" in warning[0] and "state.prev.npz" in warning[0]
    assert "resumed at iteration 2" in text.out
    assert_same_run(out, reference)


def test_no_readable_checkpoint_is_one_line(tmp_path, capsys):
    out = tmp_path / "broken"
    assert main(SMALL + ["--out", str(out), "--stop-after", "1"]) == 0
    (out / "state.npz").write_bytes(b"garbage")
    capsys.readouterr()
    assert main(SMALL + ["--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot resume from" in err and "state.npz is unreadable" in err
    assert "state.prev.npz is missing" in err and "delete the directory to start over" in err


def test_resume_with_changed_settings_names_the_change(reference, tmp_path, capsys):
    out = tmp_path / "changed"
    assert main(SMALL + ["--out", str(out), "--stop-after", "1"]) == 0
    capsys.readouterr()
    assert main(SMALL + ["--out", str(out), "--resume", "--gamma", "0.9"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "hparams.gamma: 0.99 -> 0.9" in err and "--force" in err
    assert main(SMALL + ["--out", str(out), "--resume", "--gamma", "0.9", "--force"]) == 0


@pytest.mark.parametrize("argv, message", [
    (["--lr", "-0.1"], "lr must be > 0, got -0.1"),
    (["--gamma", "1.5"], "gamma must be in [0, 1], got 1.5"),
    (["--eps-init", "1.5"], "eps_init must be in [0, 1), got 1.5"),
    (["--vf-coef", "nan"], "vf_coef must be >= 0, got nan"),
])
def test_cli_ranges(argv, message, tmp_path, capsys):
    assert main(argv + ["--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err


def test_second_writer_is_refused(tmp_path, capsys):
    """A live owner's lock refuses a second run on the directory; a dead owner's lock is taken over."""
    import subprocess
    import sys

    from gsa_jax.running.runlock import LockError, acquire, hold, release

    out = tmp_path / "locked"
    out.mkdir()
    path = acquire(str(out), "test holder")
    assert main(SMALL + ["--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"is in use by pid {os.getpid()}" in err and "test holder" in err
    release(path)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    (out / "LOCK").write_text(json.dumps({"pid": int(dead.stdout), "host": os.uname().nodename, "what": "gone"}))
    with hold(str(out), "me", log=lambda m: None):
        with pytest.raises(LockError):
            acquire(str(out), "second")
    assert not (out / "LOCK").exists()


def test_write_atomic_keeps_previous_and_cleans_up(tmp_path, monkeypatch):
    p = str(tmp_path / "f.npz")
    checkpoint.write_atomic(p, b"one", "wb", keep_previous=True)
    checkpoint.write_atomic(p, b"two", "wb", keep_previous=True)
    assert open(p, "rb").read() == b"two" and open(checkpoint.previous_path(p), "rb").read() == b"one"
    DiskFull(monkeypatch, "f.npz", 1)
    with pytest.raises(checkpoint.DiskFullError) as e:
        checkpoint.write_atomic(p, b"three" * 1000, "wb", keep_previous=True)
    assert e.value.needed == 5000 and no_temp_files(tmp_path) == []
    assert open(p, "rb").read() == b"two" and open(checkpoint.previous_path(p), "rb").read() == b"one"


def test_a_full_disk_that_no_command_names_is_one_line_and_exit_status_4(tmp_path, monkeypatch, capsys):
    """DiskFullError is an OSError and a UserError: where a command does not turn it into its own line (errors.disk_full
    names the intact checkpoint), gsa still prints one line and exits 4, no traceback."""
    from gsa_jax.errors import run_command
    from gsa_jax.errors import UserError

    p = str(tmp_path / "f.npz")
    DiskFull(monkeypatch, "f.npz", 1)
    with pytest.raises(checkpoint.DiskFullError) as e:
        checkpoint.write_atomic(p, b"x" * 100, "wb")
    assert isinstance(e.value, OSError) and isinstance(e.value, UserError) and e.value.errno == errno.ENOSPC

    def body():
        checkpoint.write_atomic(p, b"x" * 100, "wb")
        return 0

    DiskFull(monkeypatch, "f.npz", 1)
    assert run_command("train", body) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"gsa train: error: [Errno {errno.ENOSPC}] no space left writing {p}"]


def test_the_supervisor_sees_a_worker_exit_without_waiting_out_its_poll(monkeypatch):
    """wait_for_exit returns once a worker has exited (a sweep ends when its last worker does), and sleeps its whole
    interval while every worker runs."""
    from gsa_jax.running import supervise as sv

    class Proc:
        def __init__(self, polls_until_exit):
            self.left = polls_until_exit

        def poll(self):
            self.left -= 1
            return 0 if self.left <= 0 else None

    clock = {"t": 0.0}
    monkeypatch.setattr(sv.time, "monotonic", lambda: clock["t"])
    monkeypatch.setattr(sv.time, "sleep", lambda s: clock.update(t=clock["t"] + s))
    sv.wait_for_exit({0: {"proc": Proc(10**6)}, 1: {"proc": Proc(3)}}, 1.0, step_s=0.05)
    assert clock["t"] == pytest.approx(0.10)
    sv.wait_for_exit({0: {"proc": Proc(10**6)}}, 1.0, step_s=0.05)
    assert clock["t"] == pytest.approx(0.10 + 1.0)
