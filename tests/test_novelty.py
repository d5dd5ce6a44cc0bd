"""kx.novelty (SPEC section 4): k-nearest-neighbour novelty, the archive ring and the hybrid score on
hand-computed cases, held against plain-Python references on random ones; the hybrid objective and
its config checks."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx import novelty as nv
from kx.evolve import config as cfg_lib
from kx.evolve import objective as objectives

# jitted whole: one compile per shape, rather than one per primitive in eager mode
_novelty = jax.jit(nv.novelty, static_argnames="k")
_update = jax.jit(nv.update_archive)


def _archive(rows, capacity, head=None):
    """An archive holding ``rows`` in slots 0.. (head after them unless given)."""
    rows = np.asarray(rows, np.float32).reshape(-1, 2) if len(rows) else np.zeros((0, 2), np.float32)
    a = nv.init_archive(capacity, rows.shape[1])
    n = len(rows)
    return a.replace(entries=a.entries.at[:n].set(rows), size=jnp.int32(n),
                     head=jnp.int32(n % capacity if head is None else head), added=jnp.int32(n))


def _nov(points, archive=None, k=15):
    points = jnp.asarray(points, jnp.float32)
    archive = nv.init_archive(4, points.shape[1]) if archive is None else archive
    return np.asarray(_novelty(points, archive, k))


# --- k nearest neighbours ------------------------------------------------------------------------


LINE = [[0, 0], [1, 0], [3, 0], [6, 0]]  # on the x axis: pairwise distances 1, 2, 3, 3, 5, 6


def test_novelty_is_the_mean_distance_to_the_k_nearest_others():
    np.testing.assert_allclose(_nov(LINE, k=1), [1, 1, 2, 3])
    np.testing.assert_allclose(_nov(LINE, k=2), [2, 1.5, 2.5, 4])
    np.testing.assert_allclose(_nov(LINE, k=3), [10 / 3, 8 / 3, 8 / 3, 14 / 3], rtol=1e-6)


def test_fewer_neighbours_than_k_average_those_there_are_and_none_gives_zero():
    np.testing.assert_allclose(_nov(LINE, k=15), [10 / 3, 8 / 3, 8 / 3, 14 / 3], rtol=1e-6)
    np.testing.assert_array_equal(_nov([[3, 4]], k=15), [0.0])  # alone, empty archive
    np.testing.assert_array_equal(_nov([[3, 4]], _archive([], 1), k=1), [0.0])  # a capacity-1 archive, empty
    np.testing.assert_allclose(_nov([[3, 4]], _archive([[0, 0]], 5), k=15), [5.0])  # the archive only


def test_self_is_never_a_neighbour_but_an_identical_other_is():
    np.testing.assert_array_equal(_nov([[0, 0], [0, 0], [3, 4]], k=1), [0, 0, 5])
    np.testing.assert_allclose(_nov([[0, 0], [0, 0], [3, 4]], k=2), [2.5, 2.5, 5])
    np.testing.assert_array_equal(_nov([[1, 1], [1, 1]], k=15), [0, 0])


def test_ties_do_not_matter():
    # the centre has four neighbours at distance 1 and k = 2 takes any two of them
    plus = [[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]]
    got = _nov(plus, k=2)
    assert got[0] == 1.0
    np.testing.assert_allclose(got[1:], (1 + math.sqrt(2)) / 2, rtol=1e-6)
    # every order of the population gives each individual the same novelty
    perm = [3, 0, 4, 2, 1]
    np.testing.assert_array_equal(_nov(np.asarray(plus)[perm], k=2), got[perm])


def test_the_archive_counts_and_its_unfilled_slots_do_not():
    # unfilled slots hold zeros: counted, they would put a neighbour at distance 0 from (0, 0)
    a = _archive([[0, 1]], capacity=3)
    np.testing.assert_allclose(_nov([[0, 0], [10, 0]], a, k=1), [1, 10])
    np.testing.assert_allclose(_nov([[0, 0], [10, 0]], a, k=3), [5.5, (10 + math.sqrt(101)) / 2], rtol=1e-6)
    full = _archive([[0, 1], [3, 4], [6, 8]], capacity=3)
    np.testing.assert_allclose(_nov([[0, 0]], full, k=2), [3])  # 1 and 5 (the 10 left out)
    np.testing.assert_allclose(_nov([[0, 0]], full, k=3), [16 / 3], rtol=1e-6)


def _novelty_reference(points, archive_rows, k):
    out = []
    for i, x in enumerate(points):
        d = sorted([float(np.linalg.norm(x - y)) for j, y in enumerate(points) if j != i]
                   + [float(np.linalg.norm(x - y)) for y in archive_rows])
        out.append(sum(d[:k]) / len(d[:k]) if d else 0.0)
    return np.asarray(out)


@pytest.mark.parametrize("p,capacity,size,k", [(12, 10, 0, 15), (12, 10, 4, 3), (7, 5, 5, 15), (20, 30, 17, 15)])
def test_novelty_equals_a_plain_python_reference(p, capacity, size, k):
    rng = np.random.default_rng(p * 100 + size)
    points = rng.random((p, 3)).astype(np.float32)
    points[1] = points[0]  # an identical pair
    rows = rng.random((size, 3)).astype(np.float32)
    a = nv.init_archive(capacity, 3)
    a = a.replace(entries=a.entries.at[:size].set(rows), size=jnp.int32(size))
    np.testing.assert_allclose(_novelty(jnp.asarray(points), a, k), _novelty_reference(points, rows, k),
                               rtol=1e-5, atol=1e-6)


# --- the archive -------------------------------------------------------------------------------


def test_the_archive_fills_in_population_order_above_the_threshold():
    a = nv.init_archive(3, 2)
    b = jnp.asarray([[1, 1], [2, 2], [3, 3]], jnp.float32)
    a, n = _update(a, b, jnp.asarray([0.5, 0.01, 0.2]), 0.03)
    assert int(n) == 2 and int(a.size) == 2 and int(a.head) == 2 and int(a.added) == 2
    np.testing.assert_array_equal(a.entries, [[1, 1], [3, 3], [0, 0]])


def test_the_threshold_is_strict():
    a = nv.init_archive(4, 2)
    b = jnp.asarray([[1, 1], [2, 2]], jnp.float32)
    a1, n = _update(a, b, jnp.asarray([0.25, 0.5]), 0.25)
    assert int(n) == 1
    np.testing.assert_array_equal(a1.entries[0], [2, 2])
    # the default 0.03 against a float32 novelty of 0.03: equal, so not admitted
    _, n = _update(a, b, jnp.asarray([0.03, 0.03], jnp.float32), 0.03)
    assert int(n) == 0


def test_a_full_archive_replaces_its_oldest_entry():
    a = _archive([[1, 1], [2, 2]], capacity=3)
    a, n = _update(a, jnp.asarray([[3, 3], [4, 4]], jnp.float32), jnp.asarray([1.0, 1.0]), 0.03)
    # slot 2 filled, then slot 0 (the oldest, [1, 1]) replaced
    assert int(n) == 2 and int(a.size) == 3 and int(a.head) == 1 and int(a.added) == 4
    np.testing.assert_array_equal(a.entries, [[4, 4], [2, 2], [3, 3]])
    a, _ = _update(a, jnp.asarray([[5, 5]], jnp.float32), jnp.asarray([1.0]), 0.03)
    np.testing.assert_array_equal(a.entries, [[4, 4], [5, 5], [3, 3]])  # now [2, 2], the oldest, went


def test_more_admissions_than_capacity_keep_the_last_ones():
    a = _archive([[9, 9]], capacity=3)  # head 1
    b = jnp.asarray([[i, -i] for i in range(6)], jnp.float32)
    a, n = _update(a, b, jnp.asarray([1, 1, 0, 1, 1, 1], jnp.float32), 0.5)
    # admitted in order: 0, 1, 3, 4, 5 to slots 1, 2, 0, 1, 2: the last three (3, 4, 5) remain
    assert int(n) == 5 and int(a.size) == 3 and int(a.head) == (1 + 5) % 3 and int(a.added) == 6
    np.testing.assert_array_equal(a.entries, [[3, -3], [4, -4], [5, -5]])


def test_update_equals_writing_one_at_a_time():
    rng = np.random.default_rng(7)
    cap = 5
    a = nv.init_archive(cap, 2)
    ref, head, size = np.zeros((cap, 2), np.float32), 0, 0
    for _ in range(30):
        p = int(rng.choice([3, 9]))  # two shapes: two compiles
        b = rng.random((p, 2)).astype(np.float32)
        nov = rng.random(p).astype(np.float32)
        a, n = _update(a, jnp.asarray(b), jnp.asarray(nov), 0.6)
        for i in range(p):
            if nov[i] > np.float32(0.6):
                ref[head] = b[i]
                head, size = (head + 1) % cap, min(size + 1, cap)
        np.testing.assert_array_equal(a.entries, ref)
        assert (int(a.head), int(a.size)) == (head, size)


# --- the hybrid score --------------------------------------------------------------------------


def test_min_max_normalisation_and_a_constant_gives_zero():
    np.testing.assert_allclose(nv.minmax(jnp.asarray([0.2, 0.6, 0.4, 1.0])), [0, 0.5, 0.25, 1], rtol=1e-6)
    np.testing.assert_array_equal(nv.minmax(jnp.full(4, 0.7)), np.zeros(4))
    np.testing.assert_array_equal(nv.hybrid(jnp.full(3, 0.5), jnp.full(3, 2.0), 0.4), np.zeros(3))
    # constant fitness: the score is the normalised novelty's share alone
    np.testing.assert_allclose(nv.hybrid(jnp.full(3, 0.5), jnp.asarray([1.0, 3.0, 2.0]), 0.4), [0, 0.6, 0.3])


def test_hybrid_weighs_normalised_fitness_by_rho():
    fit, nov = jnp.asarray([0.0, 1.0, 2.0]), jnp.asarray([3.0, 1.0, 2.0])
    # normalised: fitness 0, 0.5, 1 and novelty 1, 0, 0.5
    np.testing.assert_allclose(nv.hybrid(fit, nov, 0.4), [0.6, 0.2, 0.7], rtol=1e-6)


def test_rho_one_ranks_as_fitness_and_rho_zero_as_novelty():
    rng = np.random.default_rng(3)
    fit, nov = jnp.asarray(rng.random(40), jnp.float32), jnp.asarray(rng.random(40) * 5, jnp.float32)
    s1, s0 = np.asarray(nv.hybrid(fit, nov, 1.0)), np.asarray(nv.hybrid(fit, nov, 0.0))
    np.testing.assert_array_equal(np.argsort(s1, kind="stable"), np.argsort(np.asarray(fit), kind="stable"))
    np.testing.assert_array_equal(np.argsort(s0, kind="stable"), np.argsort(np.asarray(nov), kind="stable"))
    assert int(np.argmax(s1)) == int(np.argmax(fit)) and int(np.argmax(s0)) == int(np.argmax(nov))


# --- one generation ----------------------------------------------------------------------------


def test_step_measures_novelty_against_the_archive_before_this_generation():
    params = nv.NoveltyParams(rho=0.4, threshold=0.03, k=1)
    fit = jnp.asarray([0.9, 0.2, 0.9])  # two champions by fitness: the first counts
    beh = jnp.asarray([[0, 0], [3, 4], [6, 8]], jnp.float32)
    step = jax.jit(nv.step)
    score, a, m = step(fit, beh, nv.init_archive(10, 2), params)
    # novelty 5, 5, 5 against an empty archive (measured after the update it would be 0)
    assert float(m["mean_novelty"]) == 5.0 and float(m["champion_novelty"]) == 5.0
    assert int(m["archive_size"]) == 3 and int(m["archive_added"]) == 3
    np.testing.assert_allclose(score, [0.4, 0.0, 0.4])  # novelty constant: 0.4 x normalised fitness
    np.testing.assert_allclose(m["score_std"], np.std([0.4, 0.0, 0.4]), rtol=1e-6)
    # the same population again: each now has an archived twin at distance 0
    score, a, m = step(fit, beh, a, params)
    assert float(m["mean_novelty"]) == 0.0 and int(m["archive_added"]) == 0 and int(m["archive_size"]) == 3
    fit2 = jnp.asarray([0.1, 0.5, 0.3])
    beh2 = jnp.asarray([[0, 1], [0, 0], [6, 5]], jnp.float32)
    _, _, m = step(fit2, beh2, a, nv.NoveltyParams(rho=0.4, threshold=0.03, k=2))
    assert float(m["champion_novelty"]) == 0.5  # (0, 0): its twin at 0 and (0, 1) at 1


def test_step_jitted_equals_step_unjitted():
    rng = np.random.default_rng(11)
    params = nv.NoveltyParams(rho=0.4, threshold=0.2, k=5)
    a = _archive(rng.random((8, 2)), capacity=20)
    fit, beh = jnp.asarray(rng.random(30), jnp.float32), jnp.asarray(rng.random((30, 2)), jnp.float32)
    want = nv.step(fit, beh, a, params)
    got = jax.jit(nv.step)(fit, beh, a, params)
    for x, y in zip(jax.tree.leaves(want), jax.tree.leaves(got), strict=True):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(want[1].entries, got[1].entries)


# --- the hybrid objective and its config -------------------------------------------------------


def _hybrid_cfg(**novelty):
    cfg = cfg_lib.base_config("neat")
    cfg.objective = "hybrid"
    cfg.novelty.update(novelty)
    return cfg


def test_the_hybrid_objective_scores_the_run_loops_behaviour_without_recompiling():
    """The objective, configured from a run config (no default values, so that a field dropped or
    swapped on the way to kx.novelty shows), against plain numpy: novelty against the archive as it was
    before the generation, the hybrid of min-max normalised fitness and novelty, the ring of admitted
    behaviours and the metrics. Generation 0 admits more than the ring holds; later ones are cut by the
    threshold."""
    k, rho, threshold, cap, p = 3, 0.7, 0.3, 10, 12
    obj = cfg_lib.validate(_hybrid_cfg(k=k, rho=rho, threshold=threshold, archive_size=cap)).objective
    assert isinstance(obj, objectives.Hybrid) and obj.name == "hybrid"
    state = obj.init(p)
    assert state.entries.shape == (cap, 3) and jax.eval_shape(lambda: obj.init(150)).entries.shape == (cap, 3)

    def minmax(x):
        return (x - x.min()) / (x.max() - x.min()) if x.max() > x.min() else np.zeros_like(x)

    ring, head, size = np.zeros((cap, 3), np.float32), 0, 0
    rng = np.random.default_rng(5)
    n_admitted = []
    for g in range(3):
        fit = rng.random(p).astype(np.float32)
        beh = rng.random((3, p)).astype(np.float32)  # [3, P] as the run loop hands it
        score, state, m = obj.score(jnp.asarray(fit), jnp.asarray(beh), state)
        nov = _novelty_reference(beh.T, ring[:size], k)  # the archive before this generation
        want = rho * minmax(fit) + (1 - rho) * minmax(nov)
        np.testing.assert_allclose(score, want, rtol=1e-5, atol=1e-6)
        admitted = [i for i in range(p) if nov[i] > threshold]
        for i in admitted:  # one at a time, in population order, the oldest overwritten once full
            ring[head] = beh[:, i]
            head, size = (head + 1) % cap, min(size + 1, cap)
        np.testing.assert_array_equal(state.entries, ring)
        assert (int(state.size), int(state.head)) == (size, head)
        assert set(m) == set(obj.metric_fields)
        assert (int(m["archive_added"]), int(m["archive_size"])) == (len(admitted), size)
        np.testing.assert_allclose(m["mean_novelty"], nov.mean(), rtol=1e-5)
        np.testing.assert_allclose(m["champion_novelty"], nov[np.argmax(fit)], rtol=1e-5)
        np.testing.assert_allclose(m["score_std"], want.std(), rtol=1e-5)
        n_admitted.append(len(admitted))
        if g == 0:
            compiled = obj._step._cache_size()  # jax shares it among jits of nv.step: count what this adds
    assert obj._step._cache_size() == compiled
    assert n_admitted[0] > cap and all(0 < n < p for n in n_admitted[1:]), n_admitted


@pytest.mark.parametrize("field,value,allowed", [
    ("k", 0, "an integer in [1, 10000]"), ("k", True, "an integer in [1, 10000]"),
    ("rho", 1.5, "a number in [0, 1]"), ("rho", -0.1, "a number in [0, 1]"),
    ("rho", float("nan"), "a number in [0, 1]"),
    ("archive_size", 0, "an integer in [1, 1000000]"),
    ("threshold", -0.01, "a finite number >= 0"), ("threshold", float("inf"), "a finite number >= 0"),
    ("normalisation", "zscore", "one of ('population', 'fixed')"),
    ("archive_rule", "novelty", "one of ('paper', 'authors')"),
    ("behaviour", "passes", "one of ('paper', 'authors')"),
])
def test_bad_novelty_fields_are_refused_by_name(field, value, allowed):
    cfg = _hybrid_cfg()
    with cfg.unlocked():
        cfg.novelty[field] = value
    with pytest.raises(objectives.ObjectiveError) as e:
        objectives.make(cfg)
    assert str(e.value) == f"novelty.{field}: allowed {allowed}, got {value!r}"
    with pytest.raises(cfg_lib.ConfigError, match=f"novelty.{field}: allowed"):
        cfg_lib.validate(cfg)
    # the section is checked whatever the objective
    cfg.objective = "fitness"
    with pytest.raises(cfg_lib.ConfigError, match=f"novelty.{field}: allowed"):
        cfg_lib.validate(cfg)


def test_the_defaults_are_the_specs():
    assert objectives.novelty_defaults() == {"k": 15, "rho": 0.4, "archive_size": 1000, "threshold": 0.03,
                                             "normalisation": "population", "archive_rule": "paper",
                                             "behaviour": "paper"}
    obj = objectives.make(_hybrid_cfg())
    assert (obj.k, obj.rho, obj.archive_size, obj.threshold) == (15, 0.4, 1000, 0.03)
    assert isinstance(objectives.make(cfg_lib.base_config("neat")), objectives.Fitness)


# --- the readings (docs/novelty.md) -----------------------------------------------------------------


def test_a_weight_of_zero_ranks_by_novelty_alone_in_a_generation():
    """rho = 0 (the authors' HyperNEAT arm): the score orders the population as its novelty does, whatever
    the fitness; rho = 1 as its fitness does (the step, archive and all)."""
    rng = np.random.default_rng(11)
    beh = jnp.asarray(rng.random((30, 3)), jnp.float32)
    fit = jnp.asarray(rng.random(30), jnp.float32)
    archive = nv.init_archive(50, 3)
    for rho, key in ((0.0, "nov"), (1.0, "fit")):
        for normalisation in nv.NORMALISATIONS:
            params = nv.NoveltyParams(rho=rho, threshold=0.03, k=5, normalisation=normalisation)
            score, _, _ = jax.jit(nv.step)(fit, beh, archive, params)
            ref = {"nov": _nov(beh, archive, k=5), "fit": np.asarray(fit)}[key]
            np.testing.assert_array_equal(np.argsort(np.asarray(score), kind="stable"), np.argsort(ref, kind="stable"))


def test_fixed_bounds_keep_the_rest_of_a_population_apart_when_one_genome_stands_far_above_it():
    """One outlier: min-max over the population squeezes the others' fitness into [0, 0.02]; fixed bounds
    leave it as it is (a share of the longest episode) and divide novelty by sqrt(D), by hand."""
    fit = jnp.asarray([0.90, 0.010, 0.015, 0.020], jnp.float32)
    nov = jnp.asarray([0.6, 0.3, 0.2, 0.1], jnp.float32)
    fixed = nv.hybrid(fit, nov, 0.4, "fixed", dim=3)
    want = [0.4 * f + 0.6 * n / math.sqrt(3) for f, n in zip([0.90, 0.010, 0.015, 0.020], [0.6, 0.3, 0.2, 0.1])]
    np.testing.assert_allclose(fixed, want, rtol=1e-6)
    pop = np.asarray(nv.hybrid(fit, nov, 0.4, "population"))
    # min-max: fitness 1, 0, 0.00562, 0.01124; novelty 1, 0.4, 0.2, 0
    np.testing.assert_allclose(pop, [1.0, 0.6 * 0.4, 0.4 * 0.005 / 0.89 + 0.6 * 0.2, 0.4 * 0.010 / 0.89], rtol=1e-5)
    with pytest.raises(ValueError, match="dim: the behaviour's dimension"):
        nv.hybrid(fit, nov, 0.4, "fixed")
    with pytest.raises(ValueError, match="normalisation: allowed population, fixed, got 'rank'"):
        nv.hybrid(fit, nov, 0.4, "rank")


def test_the_authors_archive_rule_adds_the_ten_most_novel_above_the_threshold():
    rng = np.random.default_rng(12)
    beh = jnp.asarray(rng.random((40, 3)), jnp.float32)
    nov = jnp.asarray(rng.random(40), jnp.float32).at[7].set(2.0).at[8].set(2.0)  # a tie, the most novel
    fit = jnp.zeros(40, jnp.float32).at[8].set(1.0)  # the fitter of the tie first
    update = jax.jit(nv.update_archive_authors)
    a, n = update(nv.init_archive(25, 3), beh, nov, 0.03, fit)
    order = sorted(range(40), key=lambda i: (-float(nov[i]), -float(fit[i]), i))[:10]
    assert order[:2] == [8, 7]
    assert int(n) == 10 and int(a.size) == 10 and int(a.head) == 10 and int(a.added) == 10
    np.testing.assert_array_equal(np.asarray(a.entries[:10]), np.asarray(beh)[order])
    # a second generation: 10 more into the ring, which wraps at 25
    a, n = update(a, beh, nov, 0.03, fit)
    a, n = update(a, beh, nov, 0.03, fit)
    assert int(n) == 10 and int(a.size) == 25 and int(a.head) == 5 and int(a.added) == 30
    # the ring: generation 3's 10 went to slots 20..24, then 0..4 (slots 5..19 keep generation 2's 10, then 1's)
    entries, top = np.asarray(a.entries), np.asarray(beh)[order]
    np.testing.assert_array_equal(entries[20:25], top[:5])
    np.testing.assert_array_equal(entries[0:5], top[5:])
    np.testing.assert_array_equal(entries[10:20], top)  # generation 2's
    np.testing.assert_array_equal(entries[5:10], top[5:])  # generation 1's last five, not yet overwritten
    # fewer than 10 above the threshold: only those, the threshold strict
    few = jnp.full(40, 0.03, jnp.float32).at[3].set(0.5).at[5].set(0.04)
    a, n = update(nv.init_archive(25, 3), beh, few, 0.03, fit)
    assert int(n) == 2 and int(a.size) == 2
    np.testing.assert_array_equal(np.asarray(a.entries[:2]), np.asarray(beh)[[3, 5]])
    # through the step: the archive grows by at most 10 a generation, the paper's rule by every novel one
    params = nv.NoveltyParams(rho=0.4, threshold=0.0, k=5, archive_rule="authors")
    _, a, m = jax.jit(nv.step)(fit, beh, nv.init_archive(1000, 3), params)
    assert int(m["archive_added"]) == 10 == int(a.size)
    _, a, m = jax.jit(nv.step)(fit, beh, nv.init_archive(1000, 3), params.replace(archive_rule="paper"))
    assert int(m["archive_added"]) == 40
    with pytest.raises(ValueError, match="archive_rule: allowed paper, authors, got 'all'"):
        nv.NoveltyParams(rho=0.4, threshold=0.0, archive_rule="all")


def test_a_run_written_before_the_readings_existed_reads_them_as_the_paper_s(tmp_path):
    """config.json and checkpoints of runs written before ``novelty.normalisation`` and
    ``novelty.archive_rule`` existed read them as the code before them did: resumable, and no mismatch."""
    import json

    cfg = _hybrid_cfg()
    old = cfg.to_dict()
    for f in ("normalisation", "archive_rule", "behaviour"):
        del old["novelty"][f]
    (tmp_path / "config.json").write_text(json.dumps(old))
    back = cfg_lib.read_run_config(tmp_path / "config.json")
    assert (back.novelty.normalisation, back.novelty.archive_rule, back.novelty.behaviour) == ("population", "paper",
                                                                                               "paper")
    assert cfg_lib.identity_mismatch(old, cfg) is None
    cfg.novelty.archive_rule = "authors"
    assert "novelty.archive_rule = 'paper' in the checkpoint, 'authors' now" in cfg_lib.identity_mismatch(old, cfg)


def test_the_authors_behaviour_is_time_held_dispersion_and_decisions_on_a_hand_played_episode():
    """behaviour = "authors": each trial's [time held, dispersion, decisions], decisions counting every
    iteration that began with the ball held (the holder's decision, hold included), over max_iterations.
    Hand-played 3v2: keeper 0 holds twice, passes 6 cells east (the ball flies 2 cells an iteration, so
    nobody decides while it flies), then the receiver holds to the end."""
    from conftest import make_state

    from kx.sim import env
    from kx.sim.types import KeepAwayConfig, KeepAwayParams

    config, params = KeepAwayConfig(), KeepAwayParams(max_iterations=10)
    s = make_state([(2, 2), (8, 2), (2, 12)], [(16, 16), (17, 17)], holder=0)
    step = jax.jit(lambda s, a: env.transition(s, a, jnp.int32(0), params, config))
    held_at_start = []
    for a in (0, 0, 1, 1, 1, 1, 1, 1, 1, 1):
        held_at_start.append(int(s.holder) >= 0)
        s = step(s, jnp.int32(a))
    assert bool(s.done) and int(s.t) == 10 and int(s.passes) == 1
    assert held_at_start[:3] == [True, True, True] and not all(held_at_start)  # the pass flew
    assert int(s.decisions) == sum(held_at_start) < 10
    stats = jax.tree.map(lambda a: a[..., None], env.episode_stats(s, params, config))  # a batch of one
    cfg = _hybrid_cfg()
    with cfg.unlocked():
        cfg.novelty.behaviour = "authors"
        cfg.sim.max_iterations = 10
    obj = objectives.make(cfg)
    got = np.asarray(obj.behaviour_of(stats))[:, 0]
    np.testing.assert_allclose(got, [float(stats.fitness[0]), float(stats.behaviour[1, 0]), sum(held_at_start) / 10],
                               rtol=1e-6)
    assert float(stats.fitness[0]) == 1.0  # kept to the time limit
    assert objectives.make(_hybrid_cfg()).behaviour_of(stats) is None  # the paper's: the world's own
