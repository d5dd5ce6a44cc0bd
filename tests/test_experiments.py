"""``kx.experiments``: Table 3's statistics against scipy, statsmodels and hand-computed values; a tiny
protocol interrupted mid-way that resumes and redoes no finished run; distinct per-run seeds; a report
that regenerates byte for byte wherever its folder lies; a 2 x 2 x 2 sweep and its table."""

import csv
import json
import math
import pathlib
import re
import shutil
import time
import types

import jax
import numpy as np
import pytest
import scipy.stats
import statsmodels.stats.diagnostic
import statsmodels.stats.multitest
from statsmodels.stats.nonparametric import rank_compare_2indep

from kx import runtime
from kx.evolve import checkpoint as ckpt
from kx.evolve.config import ConfigError, parse_seeds
from kx.experiments import __main__ as cli
from kx.experiments import confirm, csvfile, design, measure, planning, report, stats, sweep
from kx.experiments import progress as progress_lib
from kx.experiments import table3 as t3

# the small run config the other run tests use (test_transfer.py): its programs are compiled once
# (test states as many as the validation states: the champion plays them with the same program)
SMALL = ("population_size=12", "trials=2", "validation_trials=4", "sim.max_iterations=60", "checkpoint_every=1")


# ------------------------------------------------------------------------------------------------ statistics

def test_mann_whitney_and_the_effect_size_against_hand_computed_values_and_scipy():
    # no overlap, 3 against 3: U = 0, and the exact two-sided p is 2 / C(6, 3) = 0.1
    c = stats.mann_whitney([1.0, 2.0, 3.0], [4.0, 5.0, 6.0])
    assert (c.u, c.a, c.n_a, c.n_b) == (0.0, 0.0, 3, 3) and c.p == pytest.approx(0.1)
    # A by hand: 1 beats 0 (1), 2 beats 0 (1), each 3 ties 3 and beats 0 (1.5 twice): 5 of 8 pairs
    assert stats.vargha_delaney([1, 2, 3, 3], [3, 0]) == 0.625
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = rng.normal(0.5, 0.1, 9).round(2), rng.normal(0.55, 0.1, 11).round(2)  # rounded: ties
        c = stats.mann_whitney(a, b)
        ref = scipy.stats.mannwhitneyu(a, b, alternative="two-sided")
        assert c.u == ref.statistic and c.p == ref.pvalue
        assert c.a == pytest.approx(ref.statistic / (a.size * b.size))  # A = U / (n_a n_b)
        assert stats.vargha_delaney(b, a) == pytest.approx(1 - c.a)
    # every value equal: no evidence either way (scipy would divide by a zero variance)
    assert stats.mann_whitney([0.3, 0.3], [0.3, 0.3, 0.3]).p == 1.0
    with pytest.raises(ValueError, match="finite"):
        stats.mann_whitney([0.1, math.nan], [0.2])


def test_holm_against_hand_computed_values_and_statsmodels(monkeypatch):
    import gc

    # statsmodels' multipletests calls gc.collect() on every family: 0.2 s a call in a test worker's heap
    monkeypatch.setattr(gc, "collect", lambda *a: 0)
    # sorted 0.01, 0.03, 0.04, 0.2 times 4, 3, 2, 1 = 0.04, 0.09, 0.08 -> 0.09 (monotone), 0.2
    np.testing.assert_allclose(stats.holm([0.01, 0.04, 0.03, 0.2]), [0.04, 0.09, 0.09, 0.2])
    np.testing.assert_allclose(stats.holm([0.5, 0.6]), [1.0, 1.0])  # capped at 1
    p = np.random.default_rng(1).uniform(0, 0.2, 12)
    np.testing.assert_array_equal(stats.holm(p), statsmodels.stats.multitest.multipletests(p, method="holm")[1])
    rng = np.random.default_rng(3)
    for n in (1, 2, 9, 30):  # random families, with ties and values past 1 / n, bit for bit
        for _ in range(50):
            q = np.round(rng.random(n) ** 3, 2)
            np.testing.assert_array_equal(stats.holm(q), statsmodels.stats.multitest.multipletests(q, method="holm")[1])


def test_lilliefors_is_statsmodels_on_the_hand_computed_statistic():
    x = np.array([0.41, 0.45, 0.38, 0.52, 0.47, 0.44, 0.61, 0.39, 0.43, 0.50])
    # the statistic by hand: the largest gap between the empirical CDF and the fitted normal's
    z = np.sort((x - x.mean()) / x.std(ddof=1))
    n = x.size
    cdf = scipy.stats.norm.cdf(z)
    d = max((np.arange(1, n + 1) / n - cdf).max(), (cdf - np.arange(n) / n).max())
    stat, p = statsmodels.stats.diagnostic.lilliefors(x, dist="norm", pvalmethod="table")
    assert stat == pytest.approx(d)
    assert stats.lilliefors(x) == p and 0 < p <= 1
    assert stats.lilliefors([0.1, 0.2, 0.3]) is None and stats.lilliefors([0.2] * 6) is None


def test_iqm_and_the_bootstrap_intervals():
    assert stats.iqm(np.arange(1.0, 9.0)) == 4.5  # the middle half of 1..8: 3, 4, 5, 6
    x = np.random.default_rng(2).normal(0.5, 0.1, 10)
    ci = stats.iqm_interval(x)
    ref = scipy.stats.bootstrap((x,), lambda s, axis=-1: scipy.stats.trim_mean(s, 0.25, axis=axis),
                                n_resamples=stats.RESAMPLES, method="percentile",
                                rng=np.random.default_rng(stats.BOOTSTRAP_SEED))
    assert (ci.low, ci.high) == (ref.confidence_interval.low, ref.confidence_interval.high)
    assert ci.low < ci.value < ci.high and stats.iqm_interval(x) == ci  # the same again: seeded
    poi = stats.improvement_interval(x + 0.05, x)
    assert poi.value == stats.vargha_delaney(x + 0.05, x) and poi.low <= poi.value <= poi.high
    assert math.isnan(stats.iqm_interval([0.4]).low)  # one run: no interval
    mean, lo, hi = stats.mean_band([[0.0, 1.0], [2.0, 3.0]])
    half = scipy.stats.t.ppf(0.975, 1) * math.sqrt(2) / math.sqrt(2)
    np.testing.assert_allclose(mean, [1.0, 2.0])
    np.testing.assert_allclose(hi - mean, [half, half])
    cut = stats.mean_band([[0.0, 1.0, 9.0], [2.0, 3.0]])  # runs of unequal length: cut to the shortest
    np.testing.assert_array_equal(cut[0], mean)
    np.testing.assert_array_equal(cut[2], hi)


def test_the_permutation_interval_of_improvement_is_brunner_munzels_statistic_over_splits():
    rng = np.random.default_rng(3)
    a, b = np.round(rng.normal(0.6, 0.2, 10), 1), np.round(rng.normal(0.5, 0.1, 12), 1)  # ties within and across
    # the observed split's statistic is scipy's Brunner-Munzel statistic (b first: scipy's sign, a above b)
    both = np.concatenate([b, a])
    effect, t, _ = stats._placements(both[None], scipy.stats.rankdata(both)[None], b.size)
    assert effect[0] == pytest.approx(stats.vargha_delaney(a, b)) and t[0] == pytest.approx(
        scipy.stats.brunnermunzel(b, a).statistic)
    i = stats.improvement_permutation_interval(a, b)
    assert i.value == stats.vargha_delaney(a, b) and 0 <= i.low <= i.value <= i.high <= 1
    assert stats.improvement_permutation_interval(a, b) == i  # seeded
    back = stats.improvement_permutation_interval(b, a)  # the other way round: the same interval mirrored
    assert back.value == stats.vargha_delaney(b, a) and (back.low, back.high) == pytest.approx((1 - i.high, 1 - i.low),
                                                                                                abs=1e-15)
    # many runs: close to the t approximation's interval (statsmodels' Brunner-Munzel, its Welch df)
    x, y = rng.normal(0.3, 1.0, 60), rng.normal(0.0, 2.0, 50)
    ref = rank_compare_2indep(x, y, use_t=True).conf_int(alpha=0.05)  # its prob1, P(x > y) + P(=) / 2
    wide = stats.improvement_permutation_interval(x, y)
    assert (wide.low, wide.high) == pytest.approx(ref, abs=0.01)
    # three runs against three wholly above them: 1 split in 20 that far, 5%: not above 0.5 at 2.5% one-sided
    # (a bootstrap resamples only separated data sets and says [1, 1]); ten against ten: 1 in 184,756
    few = stats.improvement_permutation_interval([4.0, 5.0, 6.0], [1.0, 2.0, 3.0])
    assert few.value == 1 and few.low <= 0.5 and stats.improvement_interval([4.0, 5.0, 6.0], [1.0, 2.0, 3.0]).low == 1
    assert stats.improvement_permutation_interval(np.arange(10.0) + 10, np.arange(10.0)).low > 0.8
    assert stats.improvement_permutation_interval([0.3] * 4, [0.3] * 5) == stats.Interval(0.5, 0.5, 0.5)
    assert math.isnan(stats.improvement_permutation_interval([0.4], [0.1, 0.2]).low)  # one run: no interval
    with pytest.raises(ValueError, match="permutations=19 is too few"):
        stats.improvement_permutation_interval(a, b, permutations=19)


def test_van_elteren_against_hand_computed_values_and_scipy():
    # by hand: target 1 a = 3, 4 against b = 1, 2: ranks 3 + 4 = 7, E = 2 * 5 / 2 = 5, Var = 2 * 2 / 12 * 5;
    # target 2 a = 6 against b = 5, 4: rank 3, E = 1 * 4 / 2 = 2, Var = 1 * 2 / 12 * 4; weights 1/5 and 1/4
    num = (7 - 5) / 5 + (3 - 2) / 4
    var = (2 * 2 / 12 * 5) / 25 + (1 * 2 / 12 * 4) / 16
    r = stats.van_elteren([[3.0, 4.0], [6.0]], [[1.0, 2.0], [5.0, 4.0]])
    z = num / math.sqrt(var)
    assert r.z == pytest.approx(z) and r.p == pytest.approx(2 * scipy.stats.norm.sf(z))
    assert (r.strata, r.n_a, r.n_b) == (2, (2, 1), (2, 2)) and r.diff == pytest.approx(((3.5 - 1.5) + (6 - 4.5)) / 2)
    assert r.poi.value == pytest.approx((1.0 + 1.0) / 2)  # a beats b in every pair of both targets
    # one stratum, ties included: scipy's asymptotic Mann-Whitney test without the continuity correction
    rng = np.random.default_rng(3)
    for _ in range(10):
        a, b = rng.normal(0.5, 0.1, 12).round(2), rng.normal(0.55, 0.1, 9).round(2)
        ref = scipy.stats.mannwhitneyu(a, b, alternative="two-sided", method="asymptotic", use_continuity=False)
        assert stats.van_elteren([a], [b]).p == pytest.approx(ref.pvalue, rel=1e-9)
    # the sign follows a: b swapped, z negated
    assert stats.van_elteren([[1.0, 2.0], [5.0, 4.0]], [[3.0, 4.0], [6.0]]).z == pytest.approx(-r.z)
    assert stats.van_elteren([[0.3, 0.3]], [[0.3]]).p == 1.0  # nothing varies: no evidence
    with pytest.raises(ValueError, match="every stratum needs values"):
        stats.van_elteren([[0.1], []], [[0.2], [0.3]])


def _rejections(rng, shift: float, runs: int, sims: int, level: float) -> float:
    """How often van Elteren's test rejects at ``level`` on fresh samples: three targets of ``runs`` runs a
    cell, b ~ N(0, 1) and a ~ N(shift, 1) in every target."""
    strata = [(rng.normal(shift, 1.0, (sims, runs)), rng.normal(0.0, 1.0, (sims, runs))) for _ in range(3)]
    z = stats.van_elteren_z(strata)
    return float((2 * scipy.stats.norm.sf(np.abs(z)) < level).mean())


def test_the_pooled_test_rejects_identical_distributions_at_the_nominal_rate():
    rng = np.random.default_rng(4)
    for level in (0.05, 0.01):
        rate = _rejections(rng, 0.0, 20, 20000, level)
        assert abs(rate - level) < 4 * math.sqrt(level * (1 - level) / 20000) + 0.002, (level, rate)
    # runs of unequal counts and heavy ties (fitness values of short episodes): still nominal
    strata = [(rng.integers(0, 4, (20000, n)).astype(float), rng.integers(0, 4, (20000, m)).astype(float))
              for n, m in ((8, 12), (20, 20), (5, 30))]
    z = stats.van_elteren_z(strata)
    assert abs((2 * scipy.stats.norm.sf(np.abs(z)) < 0.05).mean() - 0.05) < 0.008


def test_the_power_estimate_finds_a_known_shift_at_the_stated_rate():
    """power(): resampling the observed runs at the observed effect. With many observed runs from N(0.6, 1)
    against N(0, 1), its estimate at 20 runs a cell matches the rate at which the test rejects fresh samples
    of 20 from the true distributions, and runs_needed finds the smallest count that reaches 80%."""
    rng = np.random.default_rng(5)
    level = 0.05 / 9
    a_by = [rng.normal(0.6, 1.0, 4000) for _ in range(3)]
    b_by = [rng.normal(0.0, 1.0, 4000) for _ in range(3)]
    truth = {n: _rejections(rng, 0.6, n, 4000, level) for n in (10, 20, 30)}
    for n, rate in truth.items():
        assert stats.power(a_by, b_by, level, runs=n) == pytest.approx(rate, abs=0.05), n
    need = stats.runs_needed(a_by, b_by, level, 0.8, (5, 10, 15, 20, 25, 30, 35, 40))
    assert truth[10] < 0.8 < truth[30] and need in (20, 25, 30)
    assert stats.power(a_by, b_by, level, runs=need) >= 0.8 > stats.power(a_by, b_by, level, runs=need - 5)
    # no effect: power stays at the level, and no run count reaches 80%
    null = [rng.normal(0.0, 1.0, 4000) for _ in range(3)]
    assert stats.power(null, b_by, 0.05, runs=20) == pytest.approx(0.05, abs=0.02)
    assert stats.runs_needed(null, b_by, level, 0.8, (10, 50)) is None
    # with each cell's own count (runs=None) and seeded: the same figure again
    small = [a[:10] for a in a_by], [b[:10] for b in b_by]
    assert stats.power(*small, level) == stats.power(*small, level, runs=10)


def test_the_pooled_improvement_interval_is_a_stratified_bootstrap():
    rng = np.random.default_rng(6)
    a_by = [rng.normal(0.5, 0.1, 10), rng.normal(0.6, 0.1, 12)]
    b_by = [rng.normal(0.45, 0.1, 10), rng.normal(0.6, 0.1, 8)]
    ci = stats.pooled_improvement(a_by, b_by)
    assert ci.value == pytest.approx(np.mean([stats.vargha_delaney(a, b) for a, b in zip(a_by, b_by)]))
    def poi(a, b, axis):  # P(a > b) + P(a = b) / 2 over all pairs, per resample
        a, b = np.moveaxis(a, axis, -1)[..., :, None], np.moveaxis(b, axis, -1)[..., None, :]
        return ((a > b).mean(axis=(-2, -1)) + 0.5 * (a == b).mean(axis=(-2, -1)))

    ref = scipy.stats.bootstrap((a_by[0], b_by[0], a_by[1], b_by[1]),
                                lambda a0, b0, a1, b1, axis=-1: (poi(a0, b0, axis) + poi(a1, b1, axis)) / 2,
                                n_resamples=stats.RESAMPLES, method="percentile", vectorized=True, paired=False,
                                rng=np.random.default_rng(stats.BOOTSTRAP_SEED))
    assert (ci.low, ci.high) == pytest.approx((ref.confidence_interval.low, ref.confidence_interval.high))
    assert ci.low < ci.value < ci.high


def _as_runs(cells: dict) -> dict:
    return {k: dict(enumerate(np.asarray(v, float))) for k, v in cells.items()}


#: one look at every run (a confirmatory design's), the sources shared: the test alone decides
ONE_LOOK = design.design(role="confirmatory", runs={f"{m}/{s}": 20 for m in ("neat", "hyperneat")
                                                    for s in design.PAPER_SETUPS})


def test_the_pooled_verdicts_follow_the_test_over_the_whole_family():
    """report.pooled_tests on made-up cells: a clear effect the paper's way is supported, one against it
    contradicted; Holm runs over the design's whole family (9 primary claims, the absent with p = 1) of the
    comparisons' sequential p-values; the direction is the test's, even where the probability of improvement
    averaged over the targets points the other way (a large target with a clear effect beside a small one against
    it)."""
    rng = np.random.default_rng(8)
    up = lambda n, shift: rng.normal(0.5 + shift, 0.05, n)  # noqa: E731
    cells = {("neat", "fitness", "4v3"): up(20, 0.2), ("neat", "none", "4v3"): up(20, 0.0),
             ("hyperneat", "hybrid", "4v3"): up(20, -0.2), ("hyperneat", "fitness", "4v3"): up(20, 0.0),
             ("neat", "hybrid", "4v3"): up(20, 0.01)}
    for dsg in (design.design(), ONE_LOOK):
        res = {r["claim"].key: r for r in report.pooled_tests(_as_runs(cells), dsg, power=dsg is ONE_LOOK)}
        assert set(res) == {"neat/fitness > neat/none", "hyperneat/hybrid > hyperneat/fitness",
                            "neat/hybrid > neat/none", "neat/hybrid > neat/fitness",
                            "hyperneat/fitness > neat/fitness", "hyperneat/hybrid > neat/hybrid"}
        assert res["neat/fitness > neat/none"]["verdict"] == "supported"
        assert res["hyperneat/hybrid > hyperneat/fitness"]["verdict"] == "contradicted"
        assert res["hyperneat/hybrid > hyperneat/fitness"]["way"] == -1
        p = [res[k]["seq_p"] for k in res]
        want = stats.holm(p + [1.0] * (len(report.design.PRIMARY) - len(p)))[:len(p)]
        np.testing.assert_allclose([res[k]["holm"] for k in res], want)
        assert all(r["level"] == report.design.ALPHA / 9 for r in res.values())
        if dsg is ONE_LOOK:
            assert res["neat/fitness > neat/none"]["power"] > 0.8 and res["neat/fitness > neat/none"]["needed"] <= 10
        for r in res.values():  # the pooled test is the clustered one, at the comparison's last look
            a = report._matrix(_as_runs(cells), r["claim"].a, r["targets"], dsg)
            b = report._matrix(_as_runs(cells), r["claim"].b, r["targets"], dsg)
            assert r["test"] == stats.clustered_van_elteren(a, b)
    # one look at t = 1: the sequential p is the test's own; 20 runs under the exploratory plan: its first look,
    # at 20 of 35, reads the stricter first boundary
    one = {r["claim"].key: r for r in report.pooled_tests(_as_runs(cells), ONE_LOOK, power=False)}
    two = {r["claim"].key: r for r in report.pooled_tests(_as_runs(cells), design.design(), power=False)}
    for k, r in one.items():
        assert r["seq_p"] == pytest.approx(r["test"].p, rel=1e-3, abs=1e-9)
        assert two[k]["seq_p"] >= r["seq_p"] and len(two[k]["tests"]) == 1
    # the paper's way by the statistic in a big target, against it by P averaged over a big and a tiny target
    # 4v3: 30 against 30, P(a > b) = 0.82; 5v3: 3 against 3, P = 0: averaged 0.41, but t = +3.6 (p = 0.0007)
    cells = {("neat", "fitness", "4v3"): np.arange(30) / 30 + 0.4, ("neat", "none", "4v3"): np.arange(30) / 30,
             ("neat", "fitness", "5v3"): np.array([0.1, 0.11, 0.12]),
             ("neat", "none", "5v3"): np.array([0.9, 0.91, 0.92])}
    r = next(r for r in report.pooled_tests(_as_runs(cells), ONE_LOOK, power=False)
             if r["claim"].key == "neat/fitness > neat/none")
    assert r["test"].z > 3 and r["test"].poi.value < 0.5 and r["way"] == 1
    assert r["holm"] == pytest.approx(9 * r["seq_p"]) and r["verdict"] == "supported"


def test_the_pooled_verdicts_never_go_back_to_van_elteren_with_independent_strata():
    """Transfer runs whose targets move together (one source each): van Elteren's test, the targets as independent
    strata, finds a difference the clustered test does not, and the report's verdict is the clustered test's."""
    rng = np.random.default_rng(9)
    source = rng.normal(0, 0.08, 20)  # each source's quality carries to its three targets
    noise = {t: rng.normal(0, 0.02, 20) for t in t3.TARGETS}
    base = {("neat", "none", t): rng.normal(0.5, 0.08, 20) for t in t3.TARGETS}
    for shift in np.arange(0.0, 0.15, 0.002):  # the smallest shift van Elteren's test calls significant at 0.05 / 9
        cells = base | {("neat", "fitness", t): 0.5 + shift + source + noise[t] for t in t3.TARGETS}
        z = stats.van_elteren_z([(cells[("neat", "fitness", t)][None], cells[("neat", "none", t)][None])
                                 for t in t3.TARGETS])[0]
        if 2 * scipy.stats.norm.sf(z) < 0.05 / 9:
            break
    old = report.first_kind_verdicts(_as_runs(cells))["neat/fitness > neat/none"]
    assert old[0] == "supported" and old[1] < 0.05
    r = next(r for r in report.pooled_tests(_as_runs(cells), ONE_LOOK, power=False)
             if r["claim"].key == "neat/fitness > neat/none")
    assert r["verdict"] == "not decided" and r["holm"] > 0.05 and r["test"].clusters == (20, 60)


def test_a_comparison_inside_the_margin_is_no_meaningful_difference_and_a_wide_one_not_decided():
    rng = np.random.default_rng(10)
    same = {(m, s, t): rng.normal(0.5, 0.05, 150) for m in ("neat",) for s in ("none", "fitness") for t in t3.TARGETS}
    few = {(m, s, t): rng.normal(0.5, 0.05, 8) for m in ("neat",) for s in ("none", "fitness") for t in t3.TARGETS}
    dsg = design.design(role="confirmatory", sources="per_target", runs={"neat/none": 150, "neat/fitness": 150})
    for cells, want in ((same, "no meaningful difference"), (few, "not decided")):
        r = next(r for r in report.pooled_tests(_as_runs(cells), dsg, power=False)
                 if r["claim"].key == "neat/fitness > neat/none")
        ci = r["test"].poi
        assert r["verdict"] == want and r["holm"] >= 0.05
        assert (design.MARGIN[0] <= ci.low and ci.high <= design.MARGIN[1]) == (want == "no meaningful difference")


# ------------------------------------------------------------------------------------------------- protocol

def test_every_run_of_the_full_protocol_has_its_own_seed_and_transfer_runs_their_own_source():
    specs = t3.plan(runs=20)
    sources = [s for s in specs if s.phase == "source"]
    # 20 x (NEAT, HyperNEAT: 2 sources + 3 targets x 4 setups; CMA-ES, PPO, PPO entity: 1 source + 3 targets x 2
    # setups)
    assert len(specs) == 20 * (2 * 14 + 3 * 7) and len(sources) == 20 * 7
    seeds = [t3.run_seed(0, *s.key) for s in specs]
    assert len(set(seeds)) == len(seeds)
    assert not set(seeds) & {t3.run_seed(1, *s.key) for s in specs}  # another protocol seed: other runs
    for s in specs:
        src = t3.source_of(s)
        if s.phase == "target" and s.setup in ("fitness", "hybrid"):
            want = (s.method, s.run, "source", t3.SETUPS[s.setup].objective)
            assert (src.method, src.run, src.phase, src.setup) == want
            assert src in specs[: specs.index(s)]  # a source runs before its targets
        else:
            assert src is None
    for field, bad in (("--methods", dict(methods=("neat", "sarsa"))), ("--targets", dict(targets=("7v5",))),
                       ("--setups", dict(setups=("transfer",))), ("--runs", dict(runs=0))):
        with pytest.raises(ValueError, match=field):
            t3.plan(**bad)


def test_a_folder_written_under_the_hybrids_old_setup_names_reads_as_one_written_now(tmp_path):
    """docs/table3 was written when the hybrid's setups were ``novelty`` and ``none_novelty`` (until its PPO rows,
    when the protocol wrote it again under today's names; the old file is rebuilt here from it): its rows, its design
    and its run directories read under today's names, and its runs keep the seeds they were trained with."""
    committed = pathlib.Path(__file__).resolve().parents[1] / "docs" / "table3"
    with (committed / "results.csv").open() as f:
        reader = csv.DictReader(f)
        fields, written = reader.fieldnames, list(reader)
    new_to_old = {new: old for old, new in t3.OLD_SETUPS.items()}
    old_names = tmp_path / "old" / "results.csv"
    old_names.parent.mkdir()
    with old_names.open("w", newline="") as f:
        writer = csv.DictWriter(f, fields, lineterminator="\n")
        writer.writeheader()
        writer.writerows({**r, "setup": new_to_old.get(r["setup"], r["setup"])} for r in written)
    with old_names.open() as f:
        raw = [r["setup"] for r in csv.DictReader(f)]
    rows = t3.read_results(old_names)
    assert raw.count("novelty") > 0 and raw.count("none_novelty") > 0
    assert rows == t3.read_results(committed / "results.csv")
    assert [r["setup"] for r in rows] == [t3.OLD_SETUPS.get(s, s) for s in raw]
    for r in rows:  # every recorded seed is the one today's seeding gives the row's run, under its new name
        assert int(r["seed"]) == t3.run_seed(int(r["protocol_seed"]), *t3.row_key(r)), t3.row_key(r)
    assert t3.run_seed(0, "neat", "hybrid", "target", "4v3", 0) == t3.run_seed(0, "neat", "novelty", "target", "4v3", 0)
    assert t3.run_seed(0, "neat", "hybrid", "source", "3v2", 0) != t3.run_seed(0, "neat", "novelty", "source", "3v2", 0)
    assert t3.plan(setups=("novelty", "none_novelty"), runs=1) == t3.plan(setups=("hybrid", "none_hybrid"), runs=1)
    spec = t3.RunSpec("neat", "hybrid", "target", "4v3", 0)
    assert t3.run_dir(tmp_path, spec).parent.parent.name == "target-hybrid"
    (tmp_path / "runs" / "neat" / "target-novelty" / "4v3" / "run00").mkdir(parents=True)
    assert t3.run_dir(tmp_path, spec).parent.parent.name == "target-novelty"  # a run under way there resumes
    recorded = json.loads((committed.parent / "table3_confirmatory" / "protocol.json").read_text())["design"]
    assert "neat/novelty" in recorded["runs"] and "hyperneat/novelty > neat/novelty" in json.dumps(recorded)
    dsg = design.of_folder(committed.parent / "table3_confirmatory")
    assert dsg["runs"]["neat/hybrid"] == recorded["runs"]["neat/novelty"] and "novelty" not in json.dumps(dsg["runs"])
    assert design.renamed(recorded["primary"]) == [c.key for c in design.PRIMARY]
    # the confirmatory folder, written under the old names, resumes under the new ones
    (tmp_path / "c").mkdir()
    shutil.copy(committed.parent / "table3_confirmatory" / "protocol.json", tmp_path / "c" / "protocol.json")
    opened = confirm.open_folder(tmp_path / "c", t3.Protocol.read(tmp_path / "c" / "protocol.json"), None,
                                 log=lambda s: None)
    assert {s.setup for s in confirm.specs(opened, 0, 40)} == set(design.PAPER_SETUPS)


def test_cma_es_budget_in_evaluations_equals_neats(tmp_path):
    p = t3.Protocol(source_generations=20, target_generations=50)
    neat = t3.config(p, t3.RunSpec("neat", "none", "target", "4v3", 0), tmp_path)
    cma = t3.config(p, t3.RunSpec("cma_es", "none", "target", "4v3", 0), tmp_path)
    src = t3.config(p, t3.RunSpec("cma_es", "fitness", "source", "3v2", 0), tmp_path)
    assert neat.generations * neat.population_size == cma.generations * cma.population_size == 150 * 50
    assert src.generations * src.population_size == 150 * 20 and cma.trials == neat.trials == 30


def test_every_committed_table3_run_is_built_again_as_it_ran(tmp_path):
    """docs/table3: every row's run gets the same config from table3.config as the one it ran with, as far as
    results.csv records it (seed, its source's seed, objective, population, trials, generations, episodes)."""
    committed = pathlib.Path(__file__).resolve().parents[1] / "docs" / "table3"
    protocol = t3.Protocol.read(committed / "protocol.json")
    rows = t3.read_results(committed / "results.csv")
    assert len(rows) >= 138 and len({t3.row_key(r) for r in rows}) == len(rows)
    # the test states this code draws are those the folder's runs were measured on
    recorded = json.loads((committed / "protocol.json").read_text())["test_states"]
    assert (recorded["seed"], recorded["trials"]) == (protocol.seed, protocol.test_trials)
    assert recorded["sha256"] == design.test_state_digests(protocol, (t3.SOURCE_TASK, *t3.TARGETS))
    cfgs = {t3.row_key(r): t3.config(protocol, t3.RunSpec(*t3.row_key(r)), tmp_path) for r in rows}
    for r in rows:
        run = t3.RunSpec(*t3.row_key(r))
        cfg = cfgs[run.key]
        src = t3.source_of(run)
        got = {"seed": cfg.seed, "source_seed": "" if src is None else cfgs[src.key].seed,
               "objective": cfg.objective, "population": cfg.population_size, "trials": cfg.trials,
               "generations": cfg.generations, "episodes": cfg.generations * cfg.population_size * cfg.trials}
        if cfg.method in t3.ONE_NETWORK:  # one network learning from NEAT's episodes: a generation is NEAT's 150 x 30
            got["episodes"] = cfg.generations * 150 * 30
        assert {k: str(v) for k, v in got.items()} == {k: r[k] for k in got}, t3.row_key(r)
        assert (cfg.task, cfg.method, cfg.gif) == (r["target"], r["method"], False)
        assert cfg.transfer.source == ("" if src is None else str(t3.run_dir(tmp_path, src)))


class _Interrupt(Exception):
    pass


def _tiny(tmp_path, log, batch=1, name="t3"):
    protocol = t3.Protocol(seed=3, test_trials=4, source_generations=2, target_generations=2, overrides=SMALL)
    specs = t3.plan(("neat",), ("4v3",), ("none", "fitness"), runs=2)
    return t3.run(tmp_path / name, protocol, specs, log=log, batch=batch)


@pytest.mark.slow  # ~60 s: the tiny protocol twice
def test_the_protocol_in_batched_groups_gives_the_results_of_its_runs_one_by_one(tmp_path):
    """Every column of results.csv but the times is the same whether the runs train one by one or as
    batched groups of each cell's runs (sources first), and so is the report but its table of times."""
    lines = []
    alone = _tiny(tmp_path, lambda s: None, batch=1, name="alone")
    grouped = _tiny(tmp_path, lines.append, batch=2, name="grouped")
    assert lines[0].endswith("6 to run in 3 groups of up to 2 -> " + str((tmp_path / "grouped").absolute()))
    assert any("2 runs  best" in ln or "gen 2/2" in ln for ln in lines)
    strip = lambda rows: sorted(  # noqa: E731
        ({k: str(v) for k, v in r.items() if k not in ("wall_seconds", "generation_seconds")} for r in rows),
        key=lambda r: t3.row_key(r))
    assert strip(alone) == strip(grouped)
    assert strip(t3.read_results(tmp_path / "alone" / "results.csv")) == strip(
        t3.read_results(tmp_path / "grouped" / "results.csv"))
    texts = [report.write(tmp_path / d).read_text() for d in ("alone", "grouped")]
    # the times: the Cost table's rows, and the estimate of what is still to run (in hours, from them)
    cut = lambda md: re.sub(r"\*\*[0-9.]+ hours\*\*", "", re.sub(  # noqa: E731
        r"\n\| (NEAT|HyperNEAT|CMA-ES) \| (source|target) \|[^\n]*", "", md))
    assert cut(texts[0]) == cut(texts[1])


@pytest.mark.slow  # moved out of the default suite to keep it under 7 minutes in a fresh clone
def test_a_tiny_protocol_interrupted_mid_run_resumes_and_redoes_no_finished_run(tmp_path):
    # killed during its fourth run (run 1's source): after its first checkpoint, before its second
    seen = []

    def dying(line):
        seen.append(line)
        if "[3/6 runs | neat 3v2 source (fitness) run 1] gen 2/2" in line:
            raise _Interrupt

    with pytest.raises(_Interrupt):
        _tiny(tmp_path, dying)
    out = tmp_path / "t3"
    first = t3.read_results(out / "results.csv")
    assert [(r["setup"], r["phase"], r["run"]) for r in first] == [("fitness", "source", "0"), ("none", "target", "0"),
                                                                   ("fitness", "target", "0")]
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").rglob("*") if p.is_file() and "run00" in str(p)}
    killed = t3.run_dir(out, t3.RunSpec("neat", "fitness", "source", "3v2", 1))
    assert ckpt.steps(killed) == [1]
    lines = []
    rows = _tiny(tmp_path, lines.append)
    assert lines[0].startswith("kx table3: 6 runs, 3 done, 3 to run")
    assert any("source (fitness) run 1: seeds" in ln and ln.endswith("(1 resumed)") for ln in lines)
    assert not any("run 0" in ln for ln in lines[1:])  # nothing of a finished run ran again
    assert stamps == {p: p.stat().st_mtime_ns for p in stamps}  # ... nor was a file of one touched
    assert [t3.row_key(r) for r in rows] == [t3.row_key(r) for r in t3.read_results(out / "results.csv")]
    assert len({t3.row_key(r) for r in rows}) == 6 and all(r["phase"] == "target" or r["target"] == "3v2" for r in rows)
    for r in rows:
        assert len(t3.curve(r, "best_so_far")) == 2 and 0 <= float(r["test_fitness"]) <= 1
        # every row's wall time holds its generations' times (a resumed run's charge: test_a_resumed_run_is_charged_...)
        assert float(r["wall_seconds"]) >= float(r["generation_seconds"]) > 0
        assert int(r["seed"]) == t3.run_seed(3, r["method"], r["setup"], r["phase"], r["target"], int(r["run"]))
        if r["setup"] == "fitness" and r["phase"] == "target":
            assert int(r["source_seed"]) == int(next(s["seed"] for s in rows if s["phase"] == "source"
                                                     and s["run"] == r["run"]))
            assert int(r["source_episodes"]) == 2 * 12 * 2
    # a third call has nothing to do; another protocol in the same folder is refused with the reason
    again = []
    _tiny(tmp_path, again.append)
    assert again == ["kx table3: 6 runs, 6 done, 0 to run -> " + str(out.absolute())]
    with pytest.raises(t3.RunError, match="target_generations: 2 in .*, 3 now"):
        t3.run(out, t3.Protocol(seed=3, test_trials=4, source_generations=2, target_generations=3, overrides=SMALL),
               t3.plan(("neat",), ("4v3",), ("none",), runs=1), log=lambda s: None)

    # the report, from results.csv alone, regenerates byte for byte, in another folder too
    report.write(out)
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    shutil.copy(out / "results.csv", moved / "results.csv")
    report.write(moved)
    names = ("report.md", "progression.png", "test_champions.png")
    before = {n: (out / n).read_bytes() for n in names}
    report.write(out)
    for n in names:
        assert (out / n).read_bytes() == before[n] == (moved / n).read_bytes(), n
    md = before["report.md"].decode()
    assert "| Fitness transfer | NEAT |" in md and "0.482 (0.059)" in md  # ours beside the paper's
    assert "NEAT 4v3: Fitness transfer vs No transfer" in md and "Policy transfer beats evolving from scratch" in md
    assert str(tmp_path) not in md
    # two runs a cell decide nothing: the verdict says so, with the estimate, the power and the runs needed
    assert "- max_fitness: **not decided**." in md and "- test_fitness: **not decided**." in md
    line = next(ln for ln in md.splitlines() if ln.startswith("  - NEAT: Fitness transfer vs No transfer (4v3): "))
    assert re.search(r"not decided; P\(a > b\) = [01]\.\d\d \[.*\] \((the paper's way|against the paper|neither "
                     r"way)\), mean difference [+-]\d\.\d{3}, Holm p = .*; power \d+% with these runs, (> )?\d+ runs a "
                     r"cell for 80%\.$", line), line
    assert "HyperNEAT beats NEAT.**\n- max_fitness: not measured in these runs." in md
    # what the full protocol still lacks, costed, with the commands that run it
    assert "| NEAT | target | 4v3 | No transfer | 2 | 18 |" in md and "| NEAT | source | 3v2 | fitness | 2 | 18 |" in md
    assert "| PPO | source | 3v2 | fitness | 0 | 20 | — |" in md
    assert "python -m kx.experiments table3 --runs 20 --methods neat --targets 4v3,5v3,6v4 --out <this folder>" in md


def _committed_sources(tmp_path):
    """A protocol folder as a fresh clone has it (results.csv and protocol.json, no run directories) that holds the
    two fitness sources of NEAT alone (so that one task's programs compile, not two), the plan that extends it to
    4v3, and ``refused(match, run, **changes)``: the extension refused with ``match`` once run ``run``'s row is
    edited so (the committed results.csv put back after)."""
    protocol = t3.Protocol(seed=3, test_trials=4, source_generations=2, target_generations=2, overrides=SMALL)
    out = tmp_path / "t3"
    to_4v3 = t3.plan(("neat",), ("4v3",), ("fitness",), runs=2)
    # one run a call: the programs of a run alone at test_run_loop.py's NEAT shapes (SMALL), which the resumed-run test
    # below and test_run_loop.py compile too (a group of two would compile its own)
    t3.run(out, protocol, [s for s in to_4v3 if s.phase == "source"], log=lambda s: None, batch=1)
    committed = {n: (out / n).read_bytes() for n in ("results.csv", "protocol.json")}
    assert set(json.loads(committed["protocol.json"])) >= {"test_states", "design", "seed"}
    shutil.rmtree(out / "runs")
    rows = t3.read_results(out / "results.csv")
    sources = {int(r["run"]): r for r in rows if r["phase"] == "source"}

    def edit(run, **changes):
        csvfile.write(out / "results.csv", t3.FIELDS, [dict(r, **changes) if r is sources[run] else r for r in rows])

    def refused(match, run=0, **changes):
        edit(run, **changes)
        with pytest.raises(t3.RunError, match=match):
            t3.run(out, protocol, to_4v3, log=lambda s: None)
        (out / "results.csv").write_bytes(committed["results.csv"])

    return types.SimpleNamespace(protocol=protocol, out=out, to_4v3=to_4v3, committed=committed, sources=sources,
                                 edit=edit, refused=refused)


def test_a_folder_of_only_its_committed_files_refuses_an_extension_it_cannot_trust_before_any_compute(tmp_path):
    """Extending a fresh clone's folder to a target it has no run of (4v3) is refused before any compute: a source
    whose row the protocol's config would not give now, test states or a design this code would not use."""
    f = _committed_sources(tmp_path)
    protocol, out, to_4v3, committed, refused = f.protocol, f.out, f.to_4v3, f.committed, f.refused
    refused(r"neat 3v2 source \(fitness\) run 0: its run directory .* is missing, and its row .*seed recorded 1,",
            seed="1")
    refused(r"generations recorded 3, now 2", generations="3")
    for field, value, match in (("test_states", "sha256:0", "test_states: this code draws other test states .*4v3"),
                                ("design", 0.01, "design: the statistical design recorded before the runs differs "
                                                 r"from this code's \(alpha\)")):
        edited = json.loads(committed["protocol.json"])
        if field == "test_states":
            edited[field]["sha256"]["4v3"] = value
        else:
            edited[field]["alpha"] = value
        (out / "protocol.json").write_text(json.dumps(edited))
        with pytest.raises(t3.RunError, match=match):
            t3.run(out, protocol, to_4v3, log=lambda s: None)
    (out / "protocol.json").write_bytes(committed["protocol.json"])
    assert not (out / "runs").exists()  # nothing ran


@pytest.mark.slow  # ~60 s on CI: the sources trained three times over and two targets; the refusals before any
# compute are the default suite's (the test above)
def test_a_folder_of_only_its_committed_files_extends_to_another_target(tmp_path):
    """A protocol folder as a fresh clone has it extends to a target it has no run of (4v3): its sources are
    trained again as a group, reproduce their rows, and seed the new targets. Refused: a finished source directory
    that is not the run of its row. A re-run that does not reproduce its row is set aside and seeds nothing: its
    target waits, the rest of its group is checked all the same and the other target runs."""
    f = _committed_sources(tmp_path)
    protocol, out, to_4v3, committed, edit, refused = f.protocol, f.out, f.to_4v3, f.committed, f.edit, f.refused
    src_dir = out / "runs" / "neat" / "source-fitness" / "3v2"
    # run 0's row edited where only a re-run can tell (its max fitness): both sources re-run as a group, run
    # 0's set aside, run 1's reproduced and kept; run 1's target runs, run 0's waits
    lines = []
    edit(0, max_fitness="0.5")
    with pytest.raises(t3.Waiting, match=r"^1 runs wait, .*this platform \(jax .*\): neat 4v3 Fitness transfer run "
                                         r"0\. Every other run ran"):
        t3.run(out, protocol, to_4v3, log=lines.append)
    assert "2 finished sources without a run directory trained again first" in lines[0]
    assert any(ln.endswith("source (fitness) run 1: trained again, its row reproduced (every column but the times)")
               for ln in lines)
    assert any(re.search(r"1 of 2 sources do not reproduce their rows .*source \(fitness\) run 0 \(max_fitness "
                         r"recorded 0.5, now .*set aside in .*run00.rejected\); their targets wait", ln)
               for ln in lines)
    note = json.loads((src_dir / "run00.rejected" / t3.REJECTED).read_text())
    assert note["platform"] == runtime.platform_label() and note["row"]["max_fitness"] == "0.5"
    assert (src_dir / "run00.rejected" / "config.json").is_file() and not (src_dir / "run00").exists()
    assert ckpt.steps(src_dir / "run01") == [1, 2]
    assert [r["run"] for r in t3.read_results(out / "results.csv") if r["phase"] == "target"] == ["1"]
    # called again on the same platform against the same row: run 0 is not trained again, its target still waits
    lines = []
    with pytest.raises(t3.Waiting, match="^1 runs wait"):
        t3.run(out, protocol, to_4v3, log=lines.append)
    assert any("did not reproduce its row on this platform" in ln for ln in lines)
    assert not any("(again)" in ln for ln in lines) and not (src_dir / "run00").exists()
    shutil.rmtree(out / "runs" / "neat" / "target-fitness")
    (out / "results.csv").write_bytes(committed["results.csv"])
    # run 1's finished directory is not the run of a row with another curve: refused, read not computed
    refused(r"run 1: its run directory .*run01 is not the run of its row .*best_validation from generation 2",
            run=1, best_validation=f.sources[1]["best_validation"].split()[0] + " 0.125")
    assert not (src_dir / "run00").exists()

    lines = []
    t3.run(out, protocol, to_4v3, log=lines.append)
    assert "1 finished sources without a run directory trained again first" in lines[0]
    assert any("(again)] gen 2/2" in ln and ln.endswith("(from 2 finished runs; 2 runs of kinds with none finished "
                                                       "not counted)") for ln in lines)  # no target has run yet
    assert any(ln.endswith("source (fitness) run 0: trained again, its row reproduced (every column but the times)")
               for ln in lines)
    after = (out / "results.csv").read_bytes()
    assert after.startswith(committed["results.csv"]) and after.count(b"\n") == 5  # the header, 2 sources, 2 targets
    assert [(r["phase"], r["target"]) for r in t3.read_results(out / "results.csv")[-2:]] == [("target", "4v3")] * 2
    assert (out / "protocol.json").read_bytes() == committed["protocol.json"]


def test_a_source_that_did_not_reproduce_on_this_platform_is_not_trained_again_and_its_targets_wait(tmp_path):
    """Sources set aside on this platform against the rows they still have (rejected.json) are not trained again:
    their targets wait, and the call says which runs wait and where their rows were made, with nothing trained.
    Another platform's note, or one against another row, does not count: the source is trained again there."""
    f = _committed_sources(tmp_path)
    out, rows = f.out, t3.read_results(f.out / "results.csv")
    here = runtime.platform_label()
    assert {r["platform"] for r in rows} == {here}
    src_dir = out / "runs" / "neat" / "source-fitness" / "3v2"
    for r in rows:
        d = src_dir / f"run{int(r['run']):02d}.rejected"
        d.mkdir(parents=True)
        (d / t3.REJECTED).write_text(json.dumps({"platform": here, "row": {k: r[k] for k in t3.REPRODUCED}}))
    lines = []
    with pytest.raises(t3.Waiting, match=rf"^2 runs wait, their sources' rows not reproduced on this platform "
                                         rf"\({re.escape(here)}; the rows were made on: {re.escape(here)}\): neat 4v3 "
                                         r"Fitness transfer run 0; neat 4v3 Fitness transfer run 1\. Every other run"):
        t3.run(out, f.protocol, f.to_4v3, log=lines.append)
    assert sum("did not reproduce its row on this platform" in ln for ln in lines) == 2
    assert any(ln.startswith("kx table3: 4 runs, 2 done, 2 to run (2 of them waiting for a source not reproduced "
                             "here) -> ") for ln in lines), lines
    assert sorted(p.name for p in (out / "runs").rglob("*") if p.is_dir() and p.name.startswith("run")) == [
        "run00.rejected", "run01.rejected"]  # nothing trained
    assert (out / "results.csv").read_bytes() == f.committed["results.csv"]
    d, row = src_dir / "run00", rows[0]
    assert t3._rejected_here(d, row, here)
    assert not t3._rejected_here(d, row, "jax 0.0 gpu another")  # another platform may reproduce it
    assert not t3._rejected_here(d, dict(row, max_fitness="0.5"), here)  # another row: checked again
    assert not t3._rejected_here(src_dir / "run02", row, here)


def test_results_files_from_before_the_platform_column_read_with_it_empty_and_gain_it_when_written(tmp_path):
    """A results file written before ``platform`` was recorded reads with it empty (the report then says the rows
    were made before platforms were recorded) and is written back with the column; a file lacking any other
    column is still refused."""
    path = tmp_path / "results.csv"
    old = [c for c in t3.FIELDS if c != "platform"]
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, old, lineterminator="\n")
        w.writeheader()
        w.writerow({c: "1" for c in old})
    (row,) = t3.read_results(path)
    assert list(row) == list(t3.FIELDS) and row["platform"] == ""
    csvfile.write(path, t3.FIELDS, [row])
    assert path.read_text().splitlines()[0].endswith(",best_validation,platform")
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, old[1:], lineterminator="\n")
        w.writeheader()
    with pytest.raises(t3.RunError, match="not a kx table3 results file"):
        t3.read_results(path)


def test_the_platform_label_names_the_widest_vector_instructions_of_the_cpu(monkeypatch):
    import platform

    label = runtime.platform_label()
    assert re.fullmatch(rf"jax \S+ cpu {re.escape(platform.machine())}( avx512| avx2| avx)?", label), label
    for flags, isa in ((runtime.AVX512_KERNELS | {"avx2", "fma", "avx"}, " avx512"), ({"avx2", "fma", "avx"}, " avx2"),
                       ({"avx2", "avx"}, " avx"), (set(), "")):
        monkeypatch.setattr(runtime, "cpu_flags", lambda f=flags: f)
        assert runtime.platform_label() == f"jax {jax.__version__} cpu {platform.machine()}{isa}"


def test_a_resumed_run_is_charged_its_generations_before_the_resumption(tmp_path):
    """A run killed after its first checkpoint and resumed is charged the generations its checkpoint holds
    (metrics.csv's generation_seconds, as recorded before the kill) beside the resumed call's own time; a
    generation trained past the checkpoint, trained again, is not counted twice."""
    # a 3v2 source at test_run_loop.py's NEAT shapes (SMALL): the programs that file compiles, not 4v3's of its own
    protocol = t3.Protocol(seed=3, test_trials=4, source_generations=3, target_generations=2, overrides=SMALL)
    run = tmp_path / "run"
    cfg = t3.config(protocol, t3.RunSpec("neat", "fitness", "source", "3v2", 0), tmp_path)

    def dying(line):
        if re.search(r"gen +2/3", line):
            raise _Interrupt

    with pytest.raises(_Interrupt):
        list(measure.train_and_measure([cfg], [run], 3, 4, log=dying))
    assert ckpt.steps(run) == [1]
    with (run / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["generation"] for r in rows] == ["0", "1"]  # the second generation's row, past the checkpoint
    rows[0]["generation_seconds"], rows[1]["generation_seconds"] = "1000.0", "5000.0"
    csvfile.write(run / "metrics.csv", list(rows[0]), rows)
    t0 = time.perf_counter()
    (done,) = measure.train_and_measure([cfg], [run], 3, 4, log=lambda s: None)
    took = time.perf_counter() - t0
    assert [r["generation"] for r in done.metrics] == ["0", "1", "2"]
    assert done.metrics[0]["generation_seconds"] == "1000.0"
    assert 1000 < done.wall < 1000 + took and done.share == 1 and done.wall_seconds == round(done.wall, 3)


def test_the_eta_costs_the_runs_to_go_at_the_finished_runs_of_their_kind(monkeypatch):
    """The protocol's ETA: each run to go at the mean wall time of the finished runs of its cell (results.csv's,
    then this process's), else of its method, phase and task, else of its method and phase on other tasks (said
    apart); the current group less what it has run; runs with none of these are counted apart, not guessed."""
    clock = [100.0]
    monkeypatch.setattr(progress_lib.time, "perf_counter", lambda: clock[0])
    row = lambda s, p, t, w: {"method": "neat", "setup": s, "phase": p, "target": t, "wall_seconds": str(w)}  # noqa: E731
    rows = [row("none", "target", "5v3", 100), row("none", "target", "5v3", 140), row("fitness", "source", "3v2", 20),
            row("none", "target", "4v3", 50), row("fitness", "target", "5v3", 300)]
    spec = lambda s, p, t, i: t3.RunSpec("neat", s, p, t, i)  # noqa: E731
    todo = [[spec("none", "target", "5v3", 2), spec("none", "target", "5v3", 3)], [spec("fitness", "source", "3v2", 2)],
            [spec("none", "target", "6v4", 0)], [spec("fitness", "target", "5v3", 2)],
            [spec("hybrid", "target", "5v3", 2)], [t3.RunSpec("hyperneat", "none", "target", "4v3", 0)]]
    lines = []
    progress = progress_lib.Progress(lines.append, todo, 3, 9, rows)
    progress.start(todo[0][0], "group")
    clock[0] += 30.0
    # the current group (2 x 120 s, its cell's mean) has run 30 s: 210 s left; the source 20; 6v4, with no run
    # of its task, NEAT's targets' mean (100, 140, 50, 300); fitness 5v3 its cell's 300; novelty 5v3, a cell
    # with none finished, its kind's mean (100, 140, 300); HyperNEAT, with no run at all, not costed. Rests
    # on all 5 finished runs.
    assert progress.eta() == (210.0 + 20.0 + 147.5 + 300.0 + 180.0, 5, 1, 1)
    progress.line("gen 3/50 2 runs  best 0.5  mean 0.2")
    assert lines == ["[3/9 runs | group] gen 3/50  best 0.5  protocol ETA 14.3 min (from 5 finished runs; 1 runs "
                     "costed at their method's runs of other tasks; 1 runs of kinds with none finished not counted)"]
    progress.finish(0)
    progress.add(row("none", "target", "5v3", 60))  # a run of this process: its cell's mean falls to 100 s
    progress.start(todo[1][0], "next")
    assert progress.eta() == (20.0 + 130.0 + 300.0 + 150.0, 6, 1, 1)
    # one cell's runs: the estimate rests on those alone
    one = progress_lib.Progress(lines.append, [[spec("fitness", "target", "5v3", 1)]], 0, 1, rows)
    assert one.eta()[1:] == (1, 0, 0)
    assert progress_lib.Progress(lines.append, [[t3.RunSpec("cma_es", "none", "target", "6v4", 1)]], 0, 1,
                        rows).eta_text().startswith("  protocol ETA unknown")
    # two local processes share the machine: a run's recorded wall time is half its time on the clock, and
    # the current group (2 x 2 x 120 s) has run 30 s of it
    monkeypatch.setenv(t3.processes.ENV_LOCAL, "2")
    shared = progress_lib.Progress(lines.append, todo[:2], 3, 9, rows[:3])
    shared.start(todo[0][0], "group")
    clock[0] += 30.0
    assert shared.eta() == (2 * 240.0 - 30.0 + 2 * 20.0, 3, 0, 0)


def test_the_cli_refuses_bad_input_before_any_compute(tmp_path, capsys):
    for argv, want in ((["table3", "--out", str(tmp_path / "a"), "--methods", "neat,sarsa"], "--methods: allowed neat"),
                       (["table3", "--out", str(tmp_path / "a"), "--runs", "0"], "--runs: allowed an integer >= 1"),
                       (["table3", "--out", str(tmp_path / "a"), "--set", "population_size=1"], "population_size"),
                       (["sweep", "--config", "configs/neat_3v2.py", "--grid", "neat.add_node_prob",
                         "--out", str(tmp_path / "s")], "--grid: allowed field=value1,value2"),
                       (["sweep", "--config", "configs/neat_3v2.py", "--grid", "trials=2,3", "--seeds", "3-x",
                         "--out", str(tmp_path / "s")], "--seeds: allowed"),
                       (["report", str(tmp_path / "nothing")], "no finished runs")):
        assert cli.main(argv) == 2
        assert want in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "s").exists()


@pytest.mark.slow  # ~20 s; the sweep shares the protocol's run and report code (the tiny protocol test)
def test_a_two_by_two_sweep_over_two_seeds_writes_its_table(tmp_path):
    sw = sweep.Sweep(config="configs/neat_3v2.py", grid=sweep.parse_grid(["neat.add_node_prob=0.03,0.2",
                                                                          "neat.add_link_prob=0.05,0.3"]),
                     seeds=(0, 1), test_trials=4, overrides=(*SMALL[:-1], "generations=1"))
    rows = sweep.run(tmp_path / "sw", sw, log=lambda s: None)
    assert len(rows) == 8 and len({(r["combination"], r["seed"]) for r in rows}) == 8
    path = sweep.write_report(tmp_path / "sw")
    table = [line for line in path.read_text().splitlines() if line.startswith("| neat.")]
    assert [line.split(" | ")[0] for line in table] == [
        "| neat.add_node_prob=0.03 neat.add_link_prob=0.05", "| neat.add_node_prob=0.03 neat.add_link_prob=0.3",
        "| neat.add_node_prob=0.2 neat.add_link_prob=0.05", "| neat.add_node_prob=0.2 neat.add_link_prob=0.3"]
    for line, combo in zip(table, sw.combinations()):
        tests = [float(r["test_fitness"]) for r in rows if r["overrides"] == " ".join(combo)]
        assert line.split(" | ")[1:4] == ["2", "0,1", f"{np.mean(tests):.4f}"]
    with (tmp_path / "sw" / "results.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 8
    assert (tmp_path / "sw" / "sweep.png").stat().st_size > 1000
    assert pathlib.Path(path).name == "report.md"


@pytest.mark.parametrize("text, seeds", [("0-3", [0, 1, 2, 3]), ("5", [5]), ("0-2,7", [0, 1, 2, 7]),
                                         (" 4, 2 ", [4, 2]), ("2147483647", [2**31 - 1])])
def test_seeds_parse_to_the_listed_seeds(text, seeds):
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize("text", ["x", "", "1,,2", "-2", "3-1", "0-2,2", "1,1", "2-x", "0-2147483648", "1.5"])
def test_bad_seeds_are_refused_naming_the_flag_and_the_allowed_forms(text, tmp_path, capsys):
    want = f"--seeds: allowed N, A-B or A,B,C (mixed: 0-2,7) with 0 <= seed < 2**31, each seed once, got {text!r}"
    with pytest.raises(ConfigError) as e:
        parse_seeds(text)
    assert str(e.value) == want
    argv = ["sweep", "--config", "configs/neat_3v2.py", "--grid", "trials=2,3", "--seeds", text,
            "--out", str(tmp_path / "s")]
    assert cli.main(argv) == 2
    assert capsys.readouterr().err == f"python -m kx.experiments sweep: {want}\n"
    assert not (tmp_path / "s").exists()


def _no_training(trained: list):
    """A stand-in for :func:`kx.experiments.measure.train_and_measure` that trains nothing: it records the
    run directories it is asked for and yields made-up measurements."""
    def train_and_measure(cfgs, dirs, test_seed, test_trials, log):
        for d in dirs:
            trained.append(d)
            yield types.SimpleNamespace(max_fitness=0.5, test=0.25, wall_seconds=1.0,
                                        state=types.SimpleNamespace(champion_generation=0))
    return train_and_measure


def test_two_long_combinations_sharing_their_first_120_characters_both_run_in_folders_of_their_own(
        tmp_path, monkeypatch):
    fixed = ["neat.weight_perturb_power=2.5", "neat.weight_perturb_prob=0.9", "neat.weight_mutate_rate=1.0",
             "neat.survival_threshold=0.2", "neat.compat_threshold=3.0"]
    sw = sweep.Sweep(config="configs/neat_3v2.py", grid=sweep.parse_grid([*fixed, "neat.stagnation_limit=10,15"]),
                     seeds=(0, 1), test_trials=4)
    a, b = sw.combinations()
    assert len(sweep.slug(a)) > 120 and sweep.slug(a)[:120] == sweep.slug(b)[:120]
    names = sweep.names([a, b])
    assert names[a] != names[b] and len(names[a]) == len(names[b]) == sweep.NAME_LENGTH
    assert names[a][:103] == sweep.slug(a)[:103]
    # short slugs are the names, unless two combinations share one
    assert sweep.names([("x=1",), ("x=2",)]) == {("x=1",): "x-1", ("x=2",): "x-2"}
    shared = sweep.names([("x=1.5",), ("x=1-5",)])
    assert len(set(shared.values())) == 2 and all(n.startswith("x-1-5-") for n in shared.values())

    trained = []
    monkeypatch.setattr(measure, "train_and_measure", _no_training(trained))
    rows = sweep.run(tmp_path / "sw", sw, log=lambda s: None, batch=1)
    assert len(trained) == len(set(trained)) == 4
    assert {(r["overrides"], r["seed"]) for r in rows} == {(sweep.key(c), s) for c in (a, b) for s in (0, 1)}
    assert {r["combination"] for r in rows} == {names[a], names[b]}
    trained.clear()  # run again: every run is found finished, none of the other combination's is taken for it
    assert len(sweep.run(tmp_path / "sw", sw, log=lambda s: None)) == 4 and trained == []
    with pytest.raises(ValueError, match="no spaces"):
        sweep.parse_grid(["neat.hidden_activation=a b,c"])


@pytest.mark.parametrize("name", ["neat_readings", "hyperneat_image"])
def test_the_committed_sweeps_read_as_finished_under_the_same_names(tmp_path, monkeypatch, name):
    """docs/sweeps/*: every run is found finished (nothing would run again) under the folder name it has,
    and the report regenerates byte for byte from its results.csv."""
    committed = pathlib.Path(__file__).resolve().parents[1] / "docs" / "sweeps" / name
    spec = json.loads((committed / "sweep.json").read_text())
    sw = sweep.Sweep(config=spec["config"], grid=tuple((f, tuple(v)) for f, v in spec["grid"]),
                     seeds=tuple(spec["seeds"]), test_trials=spec["test_trials"], test_seed=spec["test_seed"],
                     overrides=tuple(spec["overrides"]))
    out = tmp_path / name
    out.mkdir()
    for f in ("sweep.json", "results.csv"):
        shutil.copy(committed / f, out / f)
    trained = []
    monkeypatch.setattr(measure, "train_and_measure", _no_training(trained))
    lines = []
    rows = sweep.run(out, sw, log=lines.append)
    assert trained == [] and lines == [f"kx sweep: {len(rows)} runs, {len(rows)} done, 0 to run -> {out}"]
    names = sweep.names(sw.combinations())
    assert {(r["combination"], r["overrides"]) for r in rows} == {(names[c], sweep.key(c)) for c in sw.combinations()}
    assert sweep.write_report(out).read_bytes() == (committed / "report.md").read_bytes()


def test_the_full_protocol_estimate_costs_every_run_of_the_plan_at_its_cells_mean():

    def row(method, phase, target, wall):
        return {"method": method, "phase": phase, "target": target, "wall_seconds": str(wall)}

    rows = [row("neat", "source", "3v2", 8), row("neat", "source", "3v2", 12), row("neat", "target", "4v3", 20),
            row("hyperneat", "source", "3v2", 30), row("hyperneat", "target", "4v3", 40),
            row("hyperneat", "target", "5v3", 60), row("cma_es", "source", "3v2", 5)]
    seconds, borrowed, missing = planning.full_protocol_seconds(rows, runs=1)
    # per run index: NEAT 2 sources (fitness, hybrid) and 3 targets x 4 setups, HyperNEAT the same,
    # CMA-ES 1 source and 3 x 2 targets; HyperNEAT's 6v4 costed at its targets' mean (50)
    assert seconds == 2 * 10 + 12 * 20 + 2 * 30 + 4 * 40 + 4 * 60 + 4 * 50 + 5
    assert borrowed == {"5v3", "6v4"} and missing == {"CMA-ES target", "PPO source", "PPO target",
                                                      "PPO entity source", "PPO entity target"}
    assert ("left out, with no runs here: CMA-ES target, PPO entity source, PPO entity target, PPO source, PPO target"
            in planning.full_protocol_estimate(rows, runs=1))


def test_still_to_run_lists_each_short_cell_with_its_missing_runs_and_their_cost():

    def row(method, setup, phase, target, run, wall):
        return {"method": method, "setup": setup, "phase": phase, "target": target, "run": str(run),
                "wall_seconds": str(wall)}

    # NEAT complete at 2 runs a cell but for 6v4's fitness transfer run 1; HyperNEAT: one source and one 4v3
    # run; CMA-ES and PPO: nothing
    rows = [row("neat", o, "source", "3v2", i, 10) for o in ("fitness", "hybrid") for i in range(2)]
    rows += [row("neat", s, "target", t, i, 20 if t == "4v3" else 40) for s in t3.METHOD_SETUPS["neat"]
             for t in t3.TARGETS for i in range(2) if (s, t, i) != ("fitness", "6v4", 1)]
    rows += [row("hyperneat", "fitness", "source", "3v2", 0, 30), row("hyperneat", "none", "target", "4v3", 0, 50)]
    cells = planning.still_to_run(rows, runs=2)
    by = {(c["method"], c["phase"], c["target"], c["setup"]): c for c in cells}
    neat = [c for c in cells if c["method"] == "neat"]
    assert [(c["target"], c["setup"], c["runs"], c["missing"], c["seconds"]) for c in neat] == [
        ("6v4", "fitness", 1, 1, 40.0)]
    assert by["hyperneat", "source", "3v2", "fitness"]["missing"] == 1
    assert by["hyperneat", "source", "3v2", "hybrid"] == {
        "method": "hyperneat", "phase": "source", "target": "3v2", "setup": "hybrid", "runs": 0, "missing": 2,
        "seconds": 60.0, "borrowed": False}
    h4, h6 = by["hyperneat", "target", "4v3", "none"], by["hyperneat", "target", "6v4", "hybrid"]
    assert (h4["runs"], h4["missing"], h4["seconds"]) == (1, 1, 50.0)
    assert (h6["seconds"], h6["borrowed"]) == (100.0, True)  # 6v4 has no HyperNEAT run: its 4v3 mean, twice
    assert by["cma_es", "target", "5v3", "none"]["seconds"] is None
    assert sum(c["missing"] for c in cells) == len(t3.plan(runs=2)) - len(rows)
    assert [c["method"] for c in cells] == sorted((c["method"] for c in cells), key=t3.METHODS.index)


def test_the_finished_protocol_is_short_only_of_ppo_whose_runs_are_not_costed():
    """docs/results/protocol_full: every cell of NEAT, HyperNEAT and CMA-ES at 20 runs; what the report lists still
    to run is PPO's 7 cells on each network, with no run of PPO to cost them by, and it says so rather than "0.0
    hours"."""
    committed = pathlib.Path(__file__).resolve().parents[1] / "docs" / "results" / "protocol_full"
    rows = t3.read_results(committed / "results.csv")
    assert len(rows) == len(t3.plan(("neat", "hyperneat", "cma_es"), runs=design.RUNS_PER_CELL)) == 700
    cells = planning.still_to_run(rows)
    assert {c["method"] for c in cells} == {"ppo", "ppo_entity"} and [c["missing"] for c in cells] == [20] * 14
    text = "\n".join(report._still_to_run(rows))
    assert "In all 280 runs, none of them costed (no run of their method's phase here)." in text
    assert "hours**" not in text and "--methods ppo --targets 4v3,5v3,6v4" in text
    assert "--methods ppo_entity --targets 4v3,5v3,6v4" in text


def test_the_report_names_the_cells_extended_past_the_protocols_runs_and_the_claims_they_enter():
    from kx.experiments import report

    def row(method, setup, phase, target, run):
        return {"method": method, "setup": setup, "phase": phase, "target": target, "run": str(run)}

    # every NEAT cell at 2 runs; its hybrid transfer cells in 4v3 and 6v4 at 3, with their hybrid
    # sources; HyperNEAT's no-transfer 5v3 cell at 3
    rows = [row("neat", o, "source", "3v2", i) for o in ("fitness", "hybrid") for i in range(2)]
    rows += [row("neat", s, "target", t, i) for s in t3.METHOD_SETUPS["neat"] for t in t3.TARGETS for i in range(2)]
    rows += [row("neat", "hybrid", "source", "3v2", 2)]
    rows += [row("neat", "hybrid", "target", t, 2) for t in ("6v4", "4v3")]
    rows += [row("hyperneat", "none", "target", "5v3", i) for i in range(3)]
    cells = planning.extended_cells(rows, runs=2)
    assert [(c["method"], c["phase"], c["target"], c["setup"], c["runs"]) for c in cells] == [
        ("neat", "source", "3v2", "hybrid", 3), ("neat", "target", "4v3", "hybrid", 3),
        ("neat", "target", "6v4", "hybrid", 3), ("hyperneat", "target", "5v3", "none", 3)]
    assert cells[0]["claims"] == []
    assert cells[1]["claims"] == ["neat/hybrid > neat/none", "neat/hybrid > neat/fitness",
                                  "hyperneat/hybrid > neat/hybrid"]
    assert cells[3]["claims"] == ["hyperneat/fitness > hyperneat/none", "hyperneat/hybrid > hyperneat/none",
                                  "hyperneat/none > neat/none"]
    assert planning.extended_cells(rows, runs=3) == []
    assert report._extended([r for r in rows if r["method"] == "neat" and int(r["run"]) < 20], design.design()) == []


def test_a_recorded_design_gains_exploratory_claims_only_before_their_runs(tmp_path):
    """A folder whose design predates secondary claims (PPO's transfer on either network) gains them while the
    folder has no run of their cells (they are still fixed before their runs); with such a run, or with any other
    difference, the folder is refused."""
    protocol = t3.Protocol(seed=3, test_trials=4, overrides=SMALL)
    ppo_claim = "ppo/fitness > ppo/none"
    older = design.design()
    assert older[design.SECONDARY_KEY][-2:] == [ppo_claim, "ppo_entity/fitness > ppo_entity/none"]
    older[design.SECONDARY_KEY] = older[design.SECONDARY_KEY][:-2]
    out = tmp_path / "t3"
    out.mkdir()
    (out / "protocol.json").write_text(json.dumps({**protocol.to_json(), "design": older}))
    lines = []
    design.check_folder(out, protocol, ("3v2",), lines.append)
    assert json.loads((out / "protocol.json").read_text())["design"] == design.design()
    assert any(f"the exploratory claims {ppo_claim}, ppo_entity/fitness > ppo_entity/none (no run of theirs yet)"
               in ln for ln in lines), lines
    # a run of one of its cells exists: the claim would not be fixed before its runs
    (out / "protocol.json").write_text(json.dumps({**protocol.to_json(), "design": older}))
    csvfile.write(out / "results.csv", t3.FIELDS, [{f: "" for f in t3.FIELDS} | {
        "method": "ppo", "setup": "none", "phase": "target", "target": "4v3", "run": "0"}])
    with pytest.raises(t3.RunError, match=r"design: the statistical design recorded before the runs differs .*"
                                          r"secondary \(exploratory\)"):
        design.check_folder(out, protocol, ("3v2",), lines.append)
    # a primary claim missing is never gained
    (out / "results.csv").unlink()
    primary_cut = dict(older, primary=older["primary"][:-1])
    (out / "protocol.json").write_text(json.dumps({**protocol.to_json(), "design": primary_cut}))
    with pytest.raises(t3.RunError, match=r"differs from this code's \(primary, secondary \(exploratory\)\)"):
        design.check_folder(out, protocol, ("3v2",), lines.append)


@pytest.mark.parametrize("method", ["ppo", "ppo_entity"])
def test_the_protocols_ppo_runs_learn_from_neats_episodes(tmp_path, method):
    """PPO's runs, on either network (a population of one network; the protocol's population_size override is not
    theirs) have NEAT's generations, each of NEAT's population x trials training episodes, and the learning rate
    annealed over the run's budget; their results rows count those episodes, source and target alike."""
    protocol = t3.Protocol(seed=3, test_trials=4, source_generations=2, target_generations=3, overrides=SMALL)
    for phase, setup, task, gens in (("source", "fitness", "3v2", 2), ("target", "fitness", "4v3", 3)):
        ppo = t3.config(protocol, t3.RunSpec(method, setup, phase, task, 0), tmp_path)
        neat = t3.config(protocol, t3.RunSpec("neat", setup, phase, task, 0), tmp_path)
        assert (ppo.method, ppo.population_size, ppo.generations) == (method, 1, gens)
        assert ppo[method].episodes_per_generation == 12 * 2
        assert ppo[method].anneal_episodes == gens * 24 and t3.episodes(ppo) == t3.episodes(neat) == gens * 24
    row = t3.planned(protocol, t3.RunSpec(method, "fitness", "target", "4v3", 0), tmp_path)
    assert (row["episodes"], row["source_episodes"], row["population"]) == (72, 48, 1)
    assert t3.METHOD_SETUPS["ppo"] == ("none", "fitness")


@pytest.mark.slow  # ~60 s a method: two PPO sources and four targets
@pytest.mark.parametrize("method", ["ppo", "ppo_entity"])
def test_a_tiny_ppo_protocol_runs_its_sources_and_targets_and_reports_neats_episodes(tmp_path, method):
    """PPO's cells, on either network, run end to end through the protocol in batched groups (sources, then
    targets from their weights); their rows and the report count NEAT's episodes (a generation is a training block
    of population x trials episodes, not PPO's population of one x trials), and its claim is in the
    secondary family."""
    protocol = t3.Protocol(seed=3, test_trials=4, source_generations=2, target_generations=2, overrides=SMALL)
    rows = t3.run(tmp_path / "t3", protocol, t3.plan((method,), ("4v3",), ("none", "fitness"), runs=2),
                  log=lambda s: None, batch=2)
    name = t3.METHOD_NAMES[method]
    assert sorted((r["setup"], r["phase"], int(r["run"])) for r in rows) == [
        ("fitness", "source", 0), ("fitness", "source", 1), ("fitness", "target", 0), ("fitness", "target", 1),
        ("none", "target", 0), ("none", "target", 1)]
    for r in rows:
        assert (r["method"], int(r["population"]), int(r["episodes"])) == (method, 1, 2 * 24)
        assert int(r["source_episodes"]) == (48 if r["setup"] == "fitness" and r["phase"] == "target" else 0)
        assert 0.0 <= float(r["test_fitness"]) <= 1.0 and len(t3.curve(r, "best_so_far")) == 2
    md = report.write(tmp_path / "t3").read_text()
    assert f"- {name} source: 2 x 24 training episodes = 48 episodes" in md
    assert f"- {name} target: 2 x 24 training episodes = 48 episodes" in md
    eff = {(m, s): (g, ev) for m, t, s, _, g, ev, *_ in report.efficiency(rows)}
    g, ev = eff[(method, "none")]
    assert g in (1, 2) and ev == g * 24  # the no-transfer mean reaches its own final level by its end
    g, ev = eff[(method, "fitness")]
    assert g is None or ev == g * 24 + 48
    assert re.search(rf"\| {name} 4v3: Fitness transfer vs No transfer \| 2, 2 \|", md)


def test_a_folder_is_decided_by_the_families_its_design_recorded():
    """A claim this code adds to the secondary family (the entity policy's transfer) changes no Holm correction of a
    folder whose recorded design lacks it: its families are the recorded keys, in their order; with the claim
    recorded, the family is one larger and a claim without runs counts with p = 1."""
    today = design.design()
    recorded = {**today, design.SECONDARY_KEY: [k for k in today[design.SECONDARY_KEY]
                                                if not k.startswith("ppo_entity/")]}
    primary, secondary = design.families(recorded)
    assert [c.key for c in primary] == today["primary"] and len(secondary) == len(today[design.SECONDARY_KEY]) - 1
    old_names = {**recorded, design.SECONDARY_KEY: [k.replace("hybrid", "novelty") for k in recorded[
        design.SECONDARY_KEY]]}
    assert design.families(old_names) == (primary, secondary)  # a folder written under the old setup names
    rng = np.random.default_rng(5)
    cells = {(m, s, t): rng.normal(mu, 0.05, 20) for t in t3.TARGETS
             for m, s, mu in (("cma_es", "none", 0.3), ("cma_es", "fitness", 0.36))}
    claim = "cma_es/fitness > cma_es/none"
    by = {n: next(r for r in report.pooled_tests(_as_runs(cells), d, power=False) if r["claim"].key == claim)
          for n, d in (("recorded", recorded), ("today", today))}
    assert by["recorded"]["seq_p"] == by["today"]["seq_p"] < 0.01
    assert by["recorded"]["holm"] == pytest.approx(len(secondary) * by["recorded"]["seq_p"])
    assert by["today"]["holm"] == pytest.approx((len(secondary) + 1) * by["today"]["seq_p"])


def test_a_comparison_decided_at_its_first_look_keeps_that_looks_direction():
    """Under the exploratory plan (looks at 20 and 35 runs a cell): a first look far past its boundary sets the
    sequential p and the direction, even where the runs added later point the other way."""
    rng = np.random.default_rng(12)
    noise = lambda n: rng.normal(0, 0.01, n)  # noqa: E731
    cells = {}
    for t in t3.TARGETS:
        cells[("neat", "none", t)] = np.concatenate([1.0 + noise(20), 0.0 + noise(15)])
        cells[("neat", "none_hybrid", t)] = np.concatenate([0.5 + noise(20), 2.0 + noise(15)])
    r = next(r for r in report.pooled_tests(_as_runs(cells), design.design(), power=False)
             if r["claim"].key == "neat/none_hybrid > neat/none")
    assert len(r["tests"]) == 2 and r["tests"][0].z < -5 and r["tests"][1].z > 0
    assert r["way"] == -1 and r["verdict"] == "contradicted"


@pytest.mark.slow  # ~25 s: four tiny runs (the run loop's own re-run of a source is also the slow set's:
# test_a_folder_of_only_its_committed_files_extends_to_another_target)
def test_reproduce_trains_a_folders_runs_again_and_names_the_columns_that_differ(tmp_path, capsys):
    """``python -m kx.experiments reproduce``: one run of each method trained again from the folder's committed
    files alone (a source through the run loop's own re-run check when its target is asked for); a row
    edited by hand is caught, column by column, and the exit status says so."""
    from kx.experiments import reproduce

    protocol = t3.Protocol(seed=3, test_trials=4, source_generations=2, target_generations=2, overrides=SMALL)
    out = tmp_path / "t3"
    t3.run(out, protocol, t3.plan(("neat",), ("4v3",), ("fitness",), runs=1), log=lambda s: None)
    shutil.rmtree(out / "runs")  # a fresh clone's folder: results.csv and protocol.json
    rows = t3.read_results(out / "results.csv")
    assert reproduce.default_keys(rows) == [("neat", "fitness", "source", "3v2", 0)]
    target = ("neat", "fitness", "target", "4v3", 0)
    diffs = reproduce.reproduce(out, [target], log=lambda s: None)  # its source is trained again first, and checked
    assert diffs == {target: []}
    edited = [dict(r, max_fitness="0.5") if t3.row_key(r) == target else r for r in rows]
    csvfile.write(out / "results.csv", t3.FIELDS, edited)
    assert cli.main(["reproduce", str(out), "--row", "neat,fitness,target,4v3,0"]) == 1
    printed = capsys.readouterr().out
    assert "neat,fitness,target,4v3,0: DIFFERS: max_fitness recorded 0.5, now " in printed, printed
    assert f"; the row was made on {runtime.platform_label()}, this machine is {runtime.platform_label()}\n" in printed
    assert "reproduce: 0 of 1 rows reproduced" in printed
    with pytest.raises(ValueError, match=r"--row: allowed METHOD,SETUP,PHASE,TARGET,RUN"):
        reproduce.parse_key("neat,fitness,target,4v3")
    with pytest.raises(t3.RunError, match=r"results.csv has no row \('neat', 'none', 'target', '5v3', 0\)"):
        reproduce.reproduce(out, [("neat", "none", "target", "5v3", 0)])
