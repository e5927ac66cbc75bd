"""The benchmark end to end at a tiny size: every field of bench.json, and the plot."""

import json

from gsa_jax.bench import main, measure_mujoco_c


def test_mujoco_c_reference():
    r = measure_mujoco_c("inverted_double_pendulum", batch=16, steps=20, repeats=1)
    assert r["env_steps_per_s"] > 0 and r["physics_steps_per_s"] == r["env_steps_per_s"] * r["substeps_per_env_step"]


def test_bench_writes_report(tmp_path):
    out = tmp_path / "bench"
    assert main(["--env", "inverted_double_pendulum", "--sizes", "2", "--policies", "mixture",
                 "--processes", "2", "--repeats", "1", "--out", str(out)]) == 0
    report = json.loads((out / "bench.json").read_text())
    assert [(s["runs"], s["processes"]) for s in report["sweeps"]] == [(2, 2)]
    for s in report["sweeps"]:
        assert s["env_steps_per_s"] > 0 and s["compile_s"] > 0 and s["peak_rss_mib"] > 100
        assert abs(s["ratio_vs_mujoco_c"] - s["env_steps_per_s"] / report["mujoco_c"]["env_steps_per_s"]) < 1e-9
    assert report["versions"]["jax"] and (out / "bench.png").stat().st_size > 10_000
