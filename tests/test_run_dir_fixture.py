"""A run alone is a group of one (kx.evolve.trainer): the run directories it writes are those the code
before the one generation step wrote (tests/fixtures/run_dirs*.json, by scripts/run_dir_fixture.py at
commit 7cb4502): every metrics row but the execution columns, and every checkpoint's run state, bit for bit.

One fixture a rounding: run_dirs.json was written on a CPU with AVX-512, run_dirs_avx2.json on one with AVX2
and FMA but no AVX-512; the test takes the one written on a CPU that rounds as this one does."""

import json
import pathlib
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import run_dir_fixture  # noqa: E402

FIXTURES = {p.name: json.loads(p.read_text()) for p in sorted((REPO / "tests" / "fixtures").glob("run_dirs*.json"))}


def fixture_for_this_cpu() -> dict | None:
    """The fixture written on a CPU that rounds as this one does, with these XLA flags (None if there is none)."""
    rounding = run_dir_fixture.rounding_features
    here = (rounding(run_dir_fixture.cpu_features()), run_dir_fixture.xla_flags())
    return next((f for f in FIXTURES.values() if (rounding(f["cpu"]), f["xla_flags"]) == here), None)


def test_the_fixtures_were_written_on_cpus_that_round_differently():
    rounding = run_dir_fixture.rounding_features
    assert {"run_dirs.json", "run_dirs_avx2.json"} <= set(FIXTURES)
    written = [(tuple(rounding(f["cpu"])), tuple(f["xla_flags"])) for f in FIXTURES.values()]
    assert len(set(written)) == len(written), written
    assert all(f["runs"].keys() == run_dir_fixture.RUNS.keys() for f in FIXTURES.values())
    # the two fixtures' runs computed other floats: the rounding is what tells them apart
    a, b = FIXTURES["run_dirs.json"]["runs"], FIXTURES["run_dirs_avx2.json"]["runs"]
    assert any(a[n]["checkpoints"] != b[n]["checkpoints"] for n in a)


# HyperNEAT's run (~17 s cold) is in the slow set (the suite's 7 minutes in a fresh clone on an AVX2 CPU): the default
# suite keeps NEAT's and CMA-ES's runs here, and HyperNEAT's run directory and bit-for-bit resume in
# test_train_hyperneat.py
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "hyperneat" else n
                                  for n in sorted(run_dir_fixture.RUNS)])
def test_a_run_alone_writes_the_run_directory_the_code_before_wrote(name, tmp_path):
    fixture = fixture_for_this_cpu()
    if fixture is None:
        rounding = run_dir_fixture.rounding_features
        pytest.skip("no fixture was written on a CPU whose vector width and fused multiply-add are this one's, with "
                    f"these XLA flags ({rounding(run_dir_fixture.cpu_features())}, {run_dir_fixture.xla_flags()}; "
                    f"fixtures: {', '.join(FIXTURES)}): write one here (scripts/run_dir_fixture.py)")
    want = fixture["runs"][name]
    assert want["overrides"] == [*run_dir_fixture.SMALL, *run_dir_fixture.RUNS[name][1]]
    got = run_dir_fixture.write_run(name, tmp_path / name)
    assert len(got["rows"]) == 3 and set(got["checkpoints"]) == {"1", "2", "3"}
    diff = [(i, k, r[k], s.get(k)) for i, (r, s) in enumerate(zip(want["rows"], got["rows"])) for k in r
            if r[k] != s.get(k)]
    assert not diff, diff[:5]
    assert got["checkpoints"] == want["checkpoints"]
    if name == "neat_hybrid":  # NEAT's networks are trimmed to the hidden rows in use: some are
        assert float(got["rows"][-1]["mean_hidden"]) > 0
