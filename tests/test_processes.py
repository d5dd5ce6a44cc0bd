"""Several processes, one experiment (kx.processes): a tiny protocol run by two local processes gives the
one-process run's results, checkpoints and metrics; a process killed mid-run loses nothing; the process
files merge once, atomically; a coordinator that does not answer is a clear error, not a hang."""

import csv
import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from kx.experiments import csvfile
from kx.experiments import table3 as t3

REPO = pathlib.Path(__file__).resolve().parents[1]
TINY = ["table3", "--runs", "2", "--methods", "neat", "--targets", "4v3", "--setups", "fitness",
        "--source-generations", "2", "--target-generations", "3", "--test-trials", "4", "--seed", "3",
        "--set", "population_size=12", "--set", "trials=2", "--set", "validation_trials=4",
        "--set", "sim.max_iterations=60", "--set", "checkpoint_every=1", "--batch", "1"]
KEY = ("method", "setup", "phase", "target", "run")


def _run(args, timeout=600, **kw):
    return subprocess.run([sys.executable, "-m", "kx.experiments", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout, **kw)


def _results(out):
    with (out / "results.csv").open() as f:
        return {tuple(r[k] for k in KEY): r for r in csv.DictReader(f)}


def _same_as(one, two):
    """Every results.csv column but the times, every metrics row but the execution columns, every checkpoint's
    arrays: equal."""
    a, b = _results(one), _results(two)
    assert sorted(a) == sorted(b) and len(a) == 4
    for k in a:
        diff = [f for f in t3.REPRODUCED if a[k][f] != b[k][f]]
        assert not diff, (k, diff)
    from kx.evolve import outputs
    from kx.evolve import run as run_lib
    for k in a:
        spec = t3.RunSpec(k[0], k[1], k[2], k[3], int(k[4]))
        d1, d2 = t3.run_dir(one, spec), t3.run_dir(two, spec)
        with (d1 / "metrics.csv").open() as f1, (d2 / "metrics.csv").open() as f2:
            r1, r2 = list(csv.DictReader(f1)), list(csv.DictReader(f2))
        skip = set(outputs.EXECUTION_FIELDS)
        assert [{c: v for c, v in r.items() if c not in skip} for r in r1] == \
               [{c: v for c, v in r.items() if c not in skip} for r in r2]
        for step in (1, int(a[k]["generations"])):
            s1, s2 = run_lib.restore(d1, step)[2], run_lib.restore(d2, step)[2]
            import jax
            for x, y in zip(jax.tree.leaves(s1), jax.tree.leaves(s2)):
                np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.fixture(scope="module")
def one_process(tmp_path_factory):
    out = tmp_path_factory.mktemp("one") / "t3"
    res = _run([*TINY, "--out", str(out)])
    assert res.returncode == 0, res.stderr[-3000:]
    return out


@pytest.mark.slow  # ~60 s: three processes start (the default suite keeps the refusal and the merge)
def test_two_local_processes_give_the_one_process_results(one_process, tmp_path):
    out = tmp_path / "t3"
    res = _run([*TINY, "--processes", "2", "--out", str(out)])
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    log = res.stdout + res.stderr
    assert "[process 0]" in log and "[process 1]" in log and "the runs of index 1 mod 2" in log
    assert not list(out.glob("results.process*.csv"))  # merged into results.csv, then removed
    assert (out / "report.md").is_file()
    _same_as(one_process, out)


@pytest.mark.slow  # ~90 s: a kill, a restart
def test_a_process_killed_mid_protocol_loses_nothing(one_process, tmp_path):
    out = tmp_path / "t3"
    proc = subprocess.Popen([sys.executable, "-m", "kx.experiments", *TINY, "--processes", "2", "--out", str(out)],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    deadline = time.time() + 300
    while time.time() < deadline:  # once a process has finished a run of its own, kill the whole command
        if list(out.glob("results.process*.csv")):
            break
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert list(out.glob("results.process*.csv")) and not (out / "results.csv").is_file()
    res = _run([*TINY, "--processes", "2", "--out", str(out)])
    assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]
    _same_as(one_process, out)


def test_a_coordinator_that_does_not_answer_is_a_clear_error(tmp_path):
    import socket
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.time()
    res = _run([*TINY, "--out", str(tmp_path / "t3"), "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2",
                "--process-id", "1", "--start-timeout", "2"], timeout=120)
    assert res.returncode == 2 and time.time() - t0 < 60
    assert f"the coordinator at 127.0.0.1:{port} did not answer within 2 s" in res.stderr
    assert not (tmp_path / "t3").exists()


def test_process_files_merge_once_in_the_plans_order(tmp_path):
    path = tmp_path / "results.csv"
    row = lambda run, phase="target": {f: "" for f in t3.FIELDS} | {  # noqa: E731
        "method": "neat", "setup": "fitness" if phase == "source" else "none", "phase": phase,
        "target": "3v2" if phase == "source" else "4v3", "run": run, "best_so_far": "0", "best_validation": "0"}
    csvfile.write(path, t3.FIELDS, [row(0)])
    csvfile.write(csvfile.process_path(path, 1), t3.FIELDS, [row(3), row(1)])
    csvfile.write(csvfile.process_path(path, 0), t3.FIELDS, [row(2), row(0), row(2, "source")])
    seen = csvfile.read_all(path, t3.FIELDS, "x", t3.row_key)
    assert [(r["phase"], r["run"]) for r in seen] == [("target", "0"), ("target", "2"), ("source", "2"),
                                                      ("target", "3"), ("target", "1")]
    merged = t3.merge_results(tmp_path)
    assert [(r["phase"], r["run"]) for r in merged] == [("target", "0"), ("target", "1"), ("source", "2"),
                                                        ("target", "2"), ("target", "3")]
    assert not list(tmp_path.glob("results.process*.csv"))
    assert t3.read_results(path) == merged
    assert t3.merge_results(tmp_path) == merged  # nothing left to merge: unchanged


def test_local_processes_charge_each_run_its_share_of_the_machine(monkeypatch, tmp_path):
    """Under the local launcher, N processes share the machine's cores: each learns N from its environment
    and charges its runs 1/N more of its group's time (a run's wall_seconds is its share of the machine);
    alone, or on a cluster (no such variable), 1."""
    from kx import processes
    from kx.experiments import measure

    monkeypatch.delenv(processes.ENV_LOCAL, raising=False)
    assert processes.machine_sharers() == 1
    for bad in ("0", "two"):
        monkeypatch.setenv(processes.ENV_LOCAL, bad)
        with pytest.raises(processes.ProcessError, match=f"KX_LOCAL_PROCESSES: allowed an integer >= 1, got '{bad}'"):
            processes.machine_sharers()
    envs = []

    class Done:  # a process that has already exited, cleanly
        pid, returncode, stdout = 0, 0, ()

        def __init__(self, args, env, **kw):
            envs.append(env)

        def poll(self):
            return 0

    monkeypatch.setattr(processes.subprocess, "Popen", Done)
    assert processes.launch_local("kx.experiments", ["table3"], 3, log=lambda s: None) == 0
    assert [(e[processes.ENV_LOCAL], e[processes.ENV_ID]) for e in envs] == [("3", "0"), ("3", "1"), ("3", "2")]
    monkeypatch.setenv(processes.ENV_LOCAL, envs[1][processes.ENV_LOCAL])
    assert processes.machine_sharers() == 3
    # a group of two runs in one of the three processes: each run is charged a sixth of the group's time
    clock = iter([100.0, 112.0])
    monkeypatch.setattr(measure.time, "perf_counter", lambda: next(clock))
    monkeypatch.setattr(measure.group_lib, "train_group", lambda cfgs, dirs, resume, log: None)
    monkeypatch.setattr(measure, "champion_on_test", lambda d, seed, trials: (None, None, 0.5))
    for d in (tmp_path / "a", tmp_path / "b"):
        d.mkdir()
        (d / "metrics.csv").write_text("generation,best_fitness\n1,0.25\n")
    runs = list(measure.train_and_measure([None, None], [tmp_path / "a", tmp_path / "b"], 0, 4))
    assert [(r.share, r.wall_seconds, r.max_fitness) for r in runs] == [(6, 2.0, 0.25)] * 2


@pytest.mark.slow  # ~60 s
def test_a_sweep_under_two_processes_gives_the_one_process_results(tmp_path):
    args = ["sweep", "--config", "configs/neat_3v2.py", "--grid", "trials=2,3", "--seeds", "0-2", "--test-trials", "4",
            "--set", "population_size=12", "--set", "validation_trials=4", "--set", "sim.max_iterations=60",
            "--set", "generations=2"]
    one, two = tmp_path / "one", tmp_path / "two"
    for out, extra in ((one, []), (two, ["--processes", "2"])):
        res = _run([*args, *extra, "--out", str(out)])
        assert res.returncode == 0, (res.stdout + res.stderr)[-3000:]

    def rows(out):
        with (out / "results.csv").open() as f:
            return sorted(tuple((k, v) for k, v in r.items() if k != "wall_seconds") for r in csv.DictReader(f))

    assert len(rows(one)) == 6 and rows(one) == rows(two)
    assert not list(two.glob("results.process*.csv"))
