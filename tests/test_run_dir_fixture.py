"""A run alone is a group of one (kx.evolve.trainer): the run directories it writes are those the code
before the one generation step wrote (tests/fixtures/run_dirs.json, by scripts/run_dir_fixture.py at
commit 7cb4502): every metrics row but the execution columns, and every checkpoint's run state, bit for bit."""

import json
import pathlib
import sys

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))
import run_dir_fixture  # noqa: E402

FIXTURE = json.loads((REPO / "tests" / "fixtures" / "run_dirs.json").read_text())


@pytest.mark.parametrize("name", sorted(run_dir_fixture.RUNS))
def test_a_run_alone_writes_the_run_directory_the_code_before_wrote(name, tmp_path):
    rounding = run_dir_fixture.rounding_features
    if (rounding(FIXTURE["cpu"]) != rounding(run_dir_fixture.cpu_features())
            or FIXTURE["xla_flags"] != run_dir_fixture.xla_flags()):
        pytest.skip("the fixture was written on a CPU whose vector width or fused multiply-add differ, or with "
                    f"other XLA flags ({rounding(FIXTURE['cpu'])}, {FIXTURE['xla_flags']}): regenerate it here "
                    "(scripts/run_dir_fixture.py)")
    want = FIXTURE["runs"][name]
    assert want["overrides"] == [*run_dir_fixture.SMALL, *run_dir_fixture.RUNS[name][1]]
    got = run_dir_fixture.write_run(name, tmp_path / name)
    assert len(got["rows"]) == 3 and set(got["checkpoints"]) == {"1", "2", "3"}
    diff = [(i, k, r[k], s.get(k)) for i, (r, s) in enumerate(zip(want["rows"], got["rows"])) for k in r
            if r[k] != s.get(k)]
    assert not diff, diff[:5]
    assert got["checkpoints"] == want["checkpoints"]
    if name == "neat_hybrid":  # NEAT's networks are trimmed to the hidden rows in use: some are
        assert float(got["rows"][-1]["mean_hidden"]) > 0
