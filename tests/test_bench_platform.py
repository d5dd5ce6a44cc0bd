"""``python -m kx.bench platform``: its compare names the stage, field and episode or block where two digests
part; a digest is deterministic and agrees with the shipped reference on the episodes both hold; bad input is
refused before any compute; the reference ships as package data; the report's reading and last line; (slow)
the default run on this CPU matches the shipped reference at every stage."""

import copy
import json
import pathlib
import re
import subprocess
import sys
import tomllib
import types

import pytest

from kx.bench import platform

ROOT = pathlib.Path(__file__).resolve().parents[1]
LAST = re.compile(r"platform: (\d+) of (\d+) stages match on (\w+)(?:, (\d+) not compared)? "
                  r"\(ratio (\d\.\d\d) vs (\w+) digest\)")


def _hand_made(episodes=3, seed=0) -> dict:
    """A small digest of every stage, made by hand."""
    block = {"live": 3, **{f: 100 + i for i, f in enumerate(("keeper_x", "keeper_y", "taker_x", "done"))}}
    return {"platform": "cpu", "jax": "0.10.2", "episodes": episodes, "seed": seed,
            "starts": {"keeper_x": 1, "keeper_y": 2, "taker_x": 3, "done": 4}, "noise_words": 5, "s_max": 2,
            "reset": {"keeper_bits": 6, "taker_bits": 7, "forbidden": 8,
                      "keeper_cells": ";".join(f"{i},{i + 1},{i + 2}" for i in range(episodes)),
                      "taker_cells": ";".join(f"{i + 50},{i + 60}" for i in range(episodes)),
                      "taker_cells_by_sort": ";".join(f"{i + 50},{i + 60}" for i in range(episodes)),
                      "takers_on_forbidden_cells": 0, "taker_score_ties": 0, "parts_give_the_starts": True},
            "first_decision": 9, "kick_noise_t0_3": [10, 11, 12, 13],
            "lockstep": {"blocks": [{"after": 10 * (i + 1), **block} for i in range(4)], "mean_fitness": 0.0235,
                         "live_steps": 480},
            "evaluator": {"mean_fitness": 0.0235, "live_steps": 480, "iterations": 14, "passes": 15},
            "heuristic_min_margin": {"0.0002": {"mean_fitness": 0.0106, "live_steps": 219}}}


def _by_name(stages):
    return {s.name: s for s in stages}


def test_the_compare_names_the_first_entry_that_differs_in_each_stage():
    want = _hand_made()
    assert [s.status for s in platform.compare(copy.deepcopy(want), want)] == [platform.MATCH] * 9

    got = copy.deepcopy(want)
    got["lockstep"]["blocks"][2]["taker_x"] += 1  # block 2 (after iteration 30): taker_x, then done
    got["lockstep"]["blocks"][2]["done"] += 1
    got["lockstep"]["blocks"][3]["keeper_x"] += 1
    got["reset"]["taker_cells"] = "50,60;51,99;52,62"  # episode 1
    got["starts"]["taker_x"] = 0
    got["kick_noise_t0_3"][2] = 0
    got["heuristic_min_margin"]["0.0002"]["live_steps"] = 7
    got["evaluator"]["passes"] = 0
    s = _by_name(platform.compare(got, want))
    assert [n for n in platform.STAGES if s[n].status == platform.DIFFER] == [
        "starts", "reset", "kick_noise_t0_3", "lockstep", "evaluator", "heuristic_min_margin"]
    assert (s["lockstep"].field, s["lockstep"].where) == ("taker_x", "block 2 (after iteration 30)")
    assert "taker_x, done" in s["lockstep"].detail
    assert (s["reset"].field, s["reset"].where) == ("taker_cells", "episode 1")
    assert "cells 51,99 here, 51,61 there" in s["reset"].detail
    assert "taker_cells in 1 of 3 episodes" in s["reset"].detail
    assert s["starts"].field == "taker_x" and s["kick_noise_t0_3"].where == "iteration 2"
    assert (s["heuristic_min_margin"].field, s["heuristic_min_margin"].where) == ("live_steps", "min_margin 0.0002")
    assert s["evaluator"].field == "passes"
    assert s["lockstep"].line().startswith("lockstep              DIFFERS: first taker_x at block 2 (after "
                                           "iteration 30)")
    # the final figures alone, and a run of more blocks
    got = copy.deepcopy(want)
    got["lockstep"]["live_steps"] = 481
    assert _by_name(platform.compare(got, want))["lockstep"].field == "live_steps"
    got["lockstep"]["blocks"].append(dict(got["lockstep"]["blocks"][-1], after=50))
    assert _by_name(platform.compare(got, want))["lockstep"].where == "block 4"
    # a block whose live count and a state field differ names the state's field first
    got = copy.deepcopy(want)
    got["lockstep"]["blocks"][1].update(live=2, keeper_y=0)
    assert _by_name(platform.compare(got, want))["lockstep"].field == "keeper_y"


def test_other_episodes_compare_resets_cells_on_the_episodes_both_hold_and_other_seeds_only_s_max():
    want = _hand_made(episodes=5)
    got = _hand_made(episodes=3)
    s = _by_name(platform.compare(got, want))
    assert s["reset"].status == platform.MATCH and "first 3 episodes" in s["reset"].detail
    assert s["s_max"].status == platform.MATCH
    assert sum(x.status == platform.NOT_COMPARED for x in s.values()) == 7
    got["reset"]["keeper_cells"] = "0,1,2;1,2,3;9,9,9"
    assert (_by_name(platform.compare(got, want))["reset"].where) == "episode 2"
    other = _by_name(platform.compare(_hand_made(episodes=5, seed=1), want))
    assert [n for n, x in other.items() if x.status != platform.NOT_COMPARED] == ["s_max"]
    line = platform.summary_line("cpu", list(s.values()), "cpu")
    assert line == "platform: 2 of 9 stages match on cpu, 7 not compared (ratio 0.22 vs CPU digest)"
    assert LAST.fullmatch(line)


def test_the_verdict_tells_a_backend_from_a_jax_version():
    want = _hand_made()
    bad = copy.deepcopy(want)
    bad["first_decision"] = 0
    good, parted = platform.compare(copy.deepcopy(want), want), platform.compare(bad, want)
    assert "bit for bit" in platform.verdict({"gpu": good, "cpu": good}, "0.10.2", "0.10.2")
    assert "that backend computes differently" in platform.verdict({"gpu": parted, "cpu": good}, "0.10.2", "0.10.2")
    v = platform.verdict({"gpu": parted, "cpu": parted}, "0.11.2", "0.10.2")
    assert "the JAX version differs" in v and "first_decision" in v
    assert "host CPU backend was not run" in platform.verdict({"gpu": parted}, "0.10.2", "0.10.2")
    # against another platform's reference, a backend and a JAX version cannot be told apart
    assert "the backend or the JAX version" in platform.verdict({"cpu": parted}, "0.10.2", "0.11.2", "gpu")


@pytest.fixture(scope="module")
def small():
    """Two digests of the first 40 start states of seed 0, in this process (the second one warm)."""
    return platform.digest(40, 0), platform.digest(40, 0)


def test_a_digest_is_deterministic_and_matches_the_reference_on_the_episodes_both_hold(small):
    a, b = small
    assert a == b
    assert a["episodes"] == 40 and a["reset"]["parts_give_the_starts"] and len(a["lockstep"]["blocks"]) >= 2
    ref = platform.load_digest(platform.REFERENCE)
    s = _by_name(platform.compare(a, ref))
    assert s["reset"].status == platform.MATCH and "first 40 episodes" in s["reset"].detail, s["reset"]
    assert s["s_max"].status == platform.MATCH
    # the start states themselves: the reference's first 40 episodes' cells
    assert a["reset"]["keeper_cells"] == ";".join(ref["reset"]["keeper_cells"].split(";")[:40])
    # and a planted difference in the computed digest is found
    a2 = copy.deepcopy(a)
    a2["reset"]["keeper_cells"] = a2["reset"]["keeper_cells"].replace(";", ";0,1,2;", 1).rsplit(";", 1)[0]
    assert _by_name(platform.compare(a2, ref))["reset"].where == "episode 1"


def _args(**kw):
    base = dict(episodes=4500, seed=0, backends=None, out=None, reference=None)
    return types.SimpleNamespace(**{**base, **kw})


@pytest.mark.parametrize("kw, message", [
    (dict(episodes=0), r"--episodes: allowed an integer >= 1, got 0"),
    (dict(episodes=-3), r"--episodes: allowed an integer >= 1, got -3"),
    (dict(backends="cpu,cuda9"),
     r"--backends: allowed a comma-separated list of default, cpu, gpu, tpu, got 'cpu,cuda9'"),
    (dict(backends=","), r"--backends: allowed a comma-separated list"),
    (dict(reference="/no/such/digest.json"), r"--reference: no file /no/such/digest.json"),
    (dict(out="/no/such/folder/here.json"), r"--out: the folder of /no/such/folder/here.json does not exist"),
])
def test_bad_input_is_refused_naming_the_option_before_any_compute(kw, message, monkeypatch):
    monkeypatch.setattr(platform, "_on_backend", lambda *a: pytest.fail("computed"))
    with pytest.raises(SystemExit, match=message):
        platform.run(_args(**kw))


def test_a_reference_that_is_not_a_digest_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(platform, "_on_backend", lambda *a: pytest.fail("computed"))
    (tmp_path / "text.json").write_text("not json")
    (tmp_path / "other.json").write_text(json.dumps({"platform": "cpu", "episodes": 10}))
    with pytest.raises(SystemExit, match=r"--reference: .*text\.json is not a platform digest \(not JSON"):
        platform.run(_args(reference=str(tmp_path / "text.json")))
    with pytest.raises(SystemExit, match=r"--reference: .*other\.json is not a platform digest \(missing jax, seed"):
        platform.run(_args(reference=str(tmp_path / "other.json")))


def test_the_reference_ships_as_package_data_and_is_a_cpu_digest_of_the_default_run():
    ref = platform.load_digest(platform.REFERENCE)
    assert (ref["platform"], ref["episodes"], ref["seed"]) == ("cpu", 4500, 0)
    pins = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert f"jax=={ref['jax']}" in pins["project"]["dependencies"]  # recorded with the JAX version kx pins
    here = pathlib.Path(platform.__file__).parent
    globs = pins["tool"]["setuptools"]["package-data"]["kx.bench"]
    assert any(platform.REFERENCE in here.glob(g) for g in globs), globs
    assert any((here / "data" / "policies" / "neat_4v3.npz") in here.glob(g) for g in globs), globs


def test_the_report_reads_each_backend_and_ends_with_its_line(monkeypatch, capsys, tmp_path):
    ref = platform.load_digest(platform.REFERENCE)
    gpu = copy.deepcopy(ref)
    gpu["platform"] = "gpu"
    gpu["lockstep"]["blocks"][5]["holder"] += 1
    fake = {"default": (gpu, 2.0), "cpu": (ref, 60.0)}
    calls = []

    def on_backend(backend, episodes, seed):
        calls.append(backend)
        d, warm = fake[backend]
        return {"digest": d, "seconds_first": 3 * warm, "seconds_warm": warm, "repeat_identical": True,
                "jaxlib": "0.10.2", "devices": 1, "device_kind": "test"}

    monkeypatch.setattr(platform, "_on_backend", on_backend)
    platform.run(_args(out=str(tmp_path / "here.json")))
    out = capsys.readouterr().out.strip().splitlines()
    assert calls == ["default", "cpu"]  # the host CPU too, beside an accelerator
    assert out[-1] == "platform: 8 of 9 stages match on gpu (ratio 0.89 vs CPU digest)" and LAST.fullmatch(out[-1])
    assert out[-2] == "speed: warm digest 2.0 s on gpu, 60.0 s on the host CPU backend (ratio 30.00 vs cpu backend)"
    assert any("lockstep              DIFFERS: first holder at block 5 (after iteration 60)" in ln for ln in out)
    assert any(ln.startswith("verdict: the host CPU backend agrees") for ln in out)
    assert json.loads((tmp_path / "here.json").read_text())["platform"] == "gpu"
    assert json.loads((tmp_path / "here-cpu.json").read_text()) == ref


@pytest.mark.slow  # ~45 s on 2 cores (compilation; the default 4500 episodes, twice)
def test_the_default_run_on_this_cpu_matches_the_shipped_reference_at_every_stage():
    out = subprocess.run([sys.executable, "-m", "kx.bench", "platform", "--backends", "cpu"], capture_output=True,
                         text=True, check=True).stdout.strip().splitlines()
    assert out[-1] == "platform: 9 of 9 stages match on cpu (ratio 1.00 vs CPU digest)", "\n".join(out)
    assert any("the warm repeat identical: True" in ln for ln in out)
