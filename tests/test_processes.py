"""Several processes, one experiment (kx.experiments.processes): a tiny protocol run by two local processes gives the
one-process run's results, checkpoints and metrics; a process killed mid-run loses nothing; the process
files merge once, atomically; the processes meet through files in the experiment's folder (a handshake that
stale files cannot fool, barriers, a failed or silent process noticed), and processes that do not come are a
clear error, not a hang."""

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


def test_processes_that_do_not_come_are_a_clear_error(tmp_path):
    t0 = time.time()
    res = _run([*TINY, "--out", str(tmp_path / "t3"), "--num-processes", "2", "--process-id", "1",
                "--start-timeout", "2"], timeout=120)
    assert res.returncode == 2 and time.time() - t0 < 60
    assert "process 1 of 2: process 0 did not come within 2 s" in res.stderr
    assert not list((tmp_path / "t3").glob("*.csv")) and not (tmp_path / "t3" / "runs").exists()
    res = _run([*TINY, "--out", str(tmp_path / "t3"), "--num-processes", "2", "--process-id", "2"], timeout=120)
    assert res.returncode == 2 and "--num-processes, --process-id: allowed an integer >= 1 and one in [0, count), " \
                                   "got 2 and 2" in res.stderr


def _meet(folder, count, make=None, **kw):
    """``count`` threads that each join a Meeting in ``folder`` and pass ``make(meeting)``'s barriers; their
    meetings and the exception each raised (None)."""
    import threading

    from kx.experiments import processes

    meetings = [processes.Meeting(folder, count, i, poll_s=0.01, **kw) for i in range(count)]
    errors = [None] * count

    def body(i):
        try:
            meetings[i].join(timeout_s=20)
            if make is not None:
                make(meetings[i])
        except Exception as e:  # noqa: BLE001  (handed to the test)
            errors[i] = e

    threads = [threading.Thread(target=body, args=(i,)) for i in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in threads)
    return meetings, errors


def test_a_barrier_lets_no_process_through_before_every_process_reached_it(tmp_path):
    import random

    log, lock = [], __import__("threading").Lock()

    def work(m):
        for k in range(4):
            time.sleep(random.Random(m.index * 10 + k).random() * 0.05)  # arrive in a different order each time
            with lock:
                log.append(("arrive", k, m.index))
            m.wait(f"step {k}")
            with lock:
                log.append(("pass", k, m.index))
        m.close()

    meetings, errors = _meet(tmp_path, 3, work)
    assert errors == [None] * 3 and len({m.token for m in meetings}) == 1
    for k in range(4):  # every arrival at barrier k precedes every pass of it
        last_arrival = max(i for i, e in enumerate(log) if e[:2] == ("arrive", k))
        first_pass = min(i for i, e in enumerate(log) if e[:2] == ("pass", k))
        assert last_arrival < first_pass, (k, log)


def test_files_of_a_killed_attempt_do_not_pass_for_the_new_one(tmp_path):
    """An attempt's meeting files stay when it is killed: its session, join and acknowledgement files, and
    barriers every process reached. A new attempt makes a session of its own, waits at its own barriers and
    removes the old barrier folders."""
    from kx.experiments import processes

    first, errors = _meet(tmp_path, 2, lambda m: m.wait("start"))
    assert errors == [None, None]
    old = first[0].token
    assert (tmp_path / processes.MEETING_DIR / old / "0 start").is_dir()
    # a new attempt whose process 1 has not started: process 0 must not go on with the old files
    lone = processes.Meeting(tmp_path, 2, 0, poll_s=0.01)
    with pytest.raises(processes.ProcessError, match=r"process 0 of 2: processes 1 did not come within 1 s"):
        lone.join(timeout_s=1)
    # nor may process 1 alone take the old session for its own
    with pytest.raises(processes.ProcessError, match=r"process 1 of 2: process 0 did not come within 1 s"):
        processes.Meeting(tmp_path, 2, 1, poll_s=0.01).join(timeout_s=1)
    order = []
    second, errors = _meet(tmp_path, 2, lambda m: (m.wait("start"), order.append(m.index)))
    assert errors == [None, None] and second[0].token == second[1].token != old and sorted(order) == [0, 1]
    assert not (tmp_path / processes.MEETING_DIR / old).exists()


def test_a_failed_or_silent_process_stops_the_others_at_their_barrier(tmp_path):
    from kx.experiments import processes

    def fail_one(m):
        if m.index == 1:
            m.fail("ValueError: --runs: allowed an integer >= 1, got 0")
            return
        m.wait("start")

    t0 = time.time()
    _, errors = _meet(tmp_path / "a", 3, fail_one)
    assert time.time() - t0 < 15 and errors[1] is None
    for e in (errors[0], errors[2]):
        assert isinstance(e, processes.ProcessError)
        assert str(e) == "process 1 of 3 stopped: ValueError: --runs: allowed an integer >= 1, got 0"

    def die_one(m):  # process 1's heartbeat stops without a word (a SIGKILL, a lost host)
        if m.index == 1:
            m._stop.set()
            return
        m.wait("start")

    _, errors = _meet(tmp_path / "b", 3, die_one, heartbeat_s=0.05, dead_after_s=0.5)
    assert [type(e).__name__ for e in errors] == ["ProcessError", "NoneType", "ProcessError"]
    assert "process 1 of 3: no sign of life for 0.5 s" in str(errors[0])

    def finish_early(m):  # a process that has finished (closed) is not taken for dead, but is missed at a barrier
        m.wait("end")
        if m.index != 0:
            m.close()
            return
        time.sleep(0.8)  # past dead_after_s: process 1's heartbeat has stopped
        m.wait("after")

    _, errors = _meet(tmp_path / "c", 2, finish_early, heartbeat_s=0.05, dead_after_s=0.3)
    assert errors[1] is None and isinstance(errors[0], processes.ProcessError)
    assert str(errors[0]) == ("process 1 of 2 finished without reaching the barrier 'after' (the processes ran "
                              "different commands?)")


def test_the_process_count_and_id_come_from_a_launchers_environment(monkeypatch, tmp_path):
    from kx.experiments import processes

    for var in ("SLURM_PROCID", "SLURM_NTASKS", "OMPI_COMM_WORLD_RANK", "OMPI_COMM_WORLD_SIZE", "PMI_RANK", "PMI_SIZE",
                processes.ENV_ID, processes.ENV_COUNT):
        monkeypatch.delenv(var, raising=False)
    assert processes.initialize(tmp_path) is processes.ALONE
    with pytest.raises(processes.ProcessError, match=r"--distributed: no launcher's environment found \(read: SLURM"):
        processes.initialize(tmp_path, from_launcher=True)
    monkeypatch.setenv("OMPI_COMM_WORLD_RANK", "2")
    monkeypatch.setenv("OMPI_COMM_WORLD_SIZE", "4")
    assert processes.from_environment(True) == (4, 2) and processes.from_environment(False) is None
    monkeypatch.setenv("SLURM_PROCID", "1")
    monkeypatch.setenv("SLURM_NTASKS", "3")
    assert processes.from_environment(True) == (3, 1)  # SLURM's first
    monkeypatch.setenv(processes.ENV_ID, "0")
    monkeypatch.setenv(processes.ENV_COUNT, "1")
    assert processes.from_environment(True) == (1, 0)  # kx's own launcher's first of all
    assert processes.initialize(tmp_path, from_launcher=True) is processes.ALONE  # a count of 1: alone
    monkeypatch.setenv("SLURM_NTASKS", "x")
    monkeypatch.delenv(processes.ENV_ID)
    with pytest.raises(processes.ProcessError, match="SLURM_PROCID, SLURM_NTASKS: allowed integers, got '1', 'x'"):
        processes.from_environment(True)


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
    merged = t3.ledger(tmp_path).merge()
    assert [(r["phase"], r["run"]) for r in merged] == [("target", "0"), ("target", "1"), ("source", "2"),
                                                        ("target", "2"), ("target", "3")]
    assert not list(tmp_path.glob("results.process*.csv"))
    assert t3.read_results(path) == merged
    assert t3.ledger(tmp_path).merge() == merged  # nothing left to merge: unchanged


def test_local_processes_charge_each_run_its_share_of_the_machine(monkeypatch, tmp_path):
    """Under the local launcher, N processes share the machine's cores: each learns N from its environment
    and charges its runs 1/N more of its group's time (a run's wall_seconds is its share of the machine);
    alone, or on a cluster (no such variable), 1."""
    from kx.experiments import measure, processes

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
