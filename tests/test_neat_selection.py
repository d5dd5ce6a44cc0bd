"""Selection in NEAT's generation step: the survival threshold, elitism, selection on a score apart from
the task fitness, and the add-link cap.

Parents are identified through their weights: every genome of a population gets its own weight value
on all its genes and mutation is switched off, so a child's weights are values of its parents (crossover
takes each matching gene from one parent or the other)."""

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_neat import CFG, _init, _tell, one

from kx.neat import algorithm as alg
from kx.neat import genome as gn
from kx.neat import innovation as inn
from kx.neat.types import NEATConfig, NEATError, NEATParams

P = CFG.population_size
TAG = 0.1  # genome i carries weight (i + 1) * TAG on every gene
# No mutation at all, no interspecies mating: a child is a copy or a crossover of two members of its species.
QUIET = NEATParams(weight_mutate_prob=0.0, add_node_prob=0.0, add_link_prob=0.0, interspecies_prob=0.0,
                   target_species=4, survival_threshold=0.25)
# Every non-elite child changed: weight mutation on every gene of every child without a structural mutation.
LOUD = QUIET.replace(weight_mutate_prob=1.0, weight_mutate_rate=1.0, add_node_prob=0.05, add_link_prob=0.05)


def tagged_state(species_sizes):
    """The initial population with genome i's weights all ``(i + 1) * TAG``, in species of the given sizes
    (in population order), none stagnant."""
    state = _init(CFG)(jax.random.key(0), QUIET)
    pop = state.population
    tag = (jnp.arange(P, dtype=jnp.float32) + 1) * TAG
    pop = pop.replace(conn_weight=jnp.where(pop.conn_valid, tag[:, None], 0.0))
    sp = jnp.asarray(np.repeat(np.arange(len(species_sizes)), species_sizes), jnp.int32)
    alive = jnp.zeros((CFG.species_capacity,), bool).at[: len(species_sizes)].set(True)
    return state.replace(population=pop, species=sp, species_alive=alive)


def parents_of(children):
    """Per child, the set of genomes whose weights it carries."""
    w, valid = np.asarray(children.conn_weight), np.asarray(children.conn_valid)
    return [set((np.rint(w[i][valid[i]] / TAG).astype(int) - 1).tolist()) for i in range(w.shape[0])]


KEYS = 16  # every test's batch of keys: one program for all of them (a batch of another size compiles again)


@functools.lru_cache(maxsize=None)
def _tell_on_keys():
    return jax.jit(jax.vmap(lambda k, pop, s, st, prm, fit: alg.tell(k, pop, s, st, prm, CFG, fitness=fit),
                            in_axes=(0, None, None, None, None, None)))


def _tell_keys(with_fitness=False):
    """tell over a batch of :data:`KEYS` keys for one state and score (and task fitness), compiled once: without a
    task fitness the score is passed as it, which is what ``fitness=None`` means (``alg.tell``), so one program
    serves both (``fitness=None`` itself runs in test_neat.py)."""
    if with_fitness:
        return _tell_on_keys()
    return lambda k, pop, s, st, prm: _tell_on_keys()(k, pop, s, st, prm, s)


def test_parents_come_from_the_top_of_their_species_and_every_top_member_breeds():
    sizes = [10, 9, 5]
    state = tagged_state(sizes)
    score = 1.0 + jax.random.permutation(jax.random.key(1), P).astype(jnp.float32) / P
    keys = jax.random.split(jax.random.key(2), KEYS)
    new, m = _tell_keys()(keys, state.population, score, state, QUIET)
    n_off = np.asarray(m["offspring"][0])[: len(sizes)]
    assert n_off.sum() == P and np.all(n_off > 0)
    child_sp = np.repeat(np.arange(len(sizes)), n_off)  # children come in species order
    # The pool: floor(0.25 n) + 1 best of each species: 3 of 10, 3 of 9, 2 of 5.
    s, sp = np.asarray(score), np.asarray(state.species)
    pools = []
    for k, n in enumerate(sizes):
        members = np.flatnonzero(sp == k)
        pools.append(set(members[np.argsort(-s[members])][: int(np.floor(0.25 * n)) + 1].tolist()))
    assert [len(p) for p in pools] == [3, 3, 2]
    bred = [set() for _ in sizes]
    for r in range(keys.shape[0]):
        for i, par in enumerate(parents_of(one(new.population, r))):
            assert par <= pools[child_sp[i]], (r, i, par, pools[child_sp[i]])
            bred[child_sp[i]] |= par
    assert bred == pools  # no pool member is left out (16 generations of 8 children per species)


def test_the_champion_of_a_species_larger_than_elitism_min_size_is_copied_unchanged():
    sizes = [10, 9, 5]  # elitism_min_size 5: the species of 10 and of 9 keep their champion, that of 5 not
    state = tagged_state(sizes)
    score = 1.0 + jax.random.permutation(jax.random.key(3), P).astype(jnp.float32) / P
    keys = jax.random.split(jax.random.key(4), KEYS)
    new, m = _tell_keys()(keys, state.population, score, state, LOUD)
    n_off = np.asarray(m["offspring"][0])[: len(sizes)]
    assert np.all(n_off > 0)
    start = np.cumsum(n_off) - n_off
    s, sp = np.asarray(score), np.asarray(state.species)
    champs = [int(np.flatnonzero(sp == k)[np.argmax(s[sp == k])]) for k in range(len(sizes))]
    parent = jax.tree.map(np.asarray, state.population)
    for r in range(keys.shape[0]):
        kids = jax.tree.map(np.asarray, one(new.population, r))
        for k in (0, 1):
            chex.assert_trees_all_equal(one(kids, start[k]), one(parent, champs[k]))
        # every other child was changed by mutation: exactly the two elites equal some parent
        same = [i for i in range(P) if any(jax.tree.all(jax.tree.map(np.array_equal, one(kids, i), one(parent, j)))
                                           for j in range(P))]
        assert same == [start[0], start[1]], (r, same)


def test_selection_follows_the_score_and_reports_follow_the_fitness():
    state = tagged_state([P])  # one species: the pool is the floor(0.25 * 24) + 1 = 7 best
    # Genome i has i % 8 + 1 enabled links, so the champions' sizes tell them apart.
    pop = state.population
    en = pop.conn_valid & (jnp.arange(pop.conn_valid.shape[1])[None, :] <= (jnp.arange(P) % 8)[:, None])
    state = state.replace(population=pop.replace(conn_enabled=en))
    fitness = jax.random.permutation(jax.random.key(5), P).astype(jnp.float32)  # 0..23
    score = (P - 1) - fitness  # a permutation of the fitness values: the best by score is the worst by fitness
    keys = jax.random.split(jax.random.key(6), KEYS)
    new, m = _tell_keys(True)(keys, state.population, score, state, QUIET, fitness)
    f = np.asarray(fitness)
    by_score = set(np.argsort(-np.asarray(score))[:7].tolist())
    assert by_score.isdisjoint(np.argsort(-f)[:7].tolist())
    top_s, top_f = int(np.argmax(np.asarray(score))), int(np.argmax(f))
    for r in range(keys.shape[0]):
        kids = one(new.population, r)
        assert all(par <= by_score for par in parents_of(kids))
        chex.assert_trees_all_equal(one(kids, 0), one(state.population, top_s))  # the elite: best by score
        chex.assert_trees_all_equal(one(new.best_genome, r), one(state.population, top_f))
    assert np.all(np.asarray(new.best_fitness) == P - 1)
    mr = jax.tree.map(lambda x: np.asarray(x)[0], m)
    assert (mr["best_fitness"], mr["mean_fitness"], mr["median_fitness"]) == (P - 1, (P - 1) / 2, (P - 1) / 2)
    assert mr["champion_links"] == top_f % 8 + 1 != top_s % 8 + 1
    # fitness=None is selection and reporting on the score
    _, m_s = _tell(CFG)(keys[0], state.population, score, state, QUIET)
    assert int(m_s["champion_links"]) == top_s % 8 + 1


def test_stagnation_follows_the_task_fitness_and_spares_the_top_score_and_the_fittest_genome():
    """Records are the species' best task fitness (a quantity comparable across generations), not the
    score. Generation 20, every species last improved at 0 with a record of 10 (species 2: 50):
    species 0 holds the best score (20) but a stalled fitness (3): spared; species 1's fitness (11)
    beats its record with a low score (2): improved; species 2 holds the fittest genome (12, below its
    record 50): spared; species 3's score (11) beats 10 but its fitness (4) does not: stagnant, the
    only one (on the score, as before, species 3 would have counted as improving and species 2 culled)."""
    state = tagged_state([6, 6, 6, 6]).replace(
        generation=jnp.int32(20),
        species_best=jnp.full((CFG.species_capacity,), 10.0, jnp.float32).at[2].set(50.0),
        species_improved=jnp.zeros((CFG.species_capacity,), jnp.int32))
    sp = np.asarray(state.species)
    fitness = jnp.asarray(np.select([sp == 0, sp == 1, sp == 2], [3.0, 11.0, 12.0], 4.0), jnp.float32)
    score = jnp.asarray(np.select([sp == 0, sp == 1, sp == 2], [20.0, 2.0, 5.0], 11.0), jnp.float32)
    # over the file's batch of keys (its one program with a task fitness): none of this depends on the key
    new, m = _tell_keys(True)(jax.random.split(jax.random.key(7), KEYS), state.population, score, state, QUIET,
                              fitness)
    for r in range(KEYS):
        n_off = np.asarray(m["offspring"])[r, :4]
        assert n_off[0] > 0 and n_off[1] > 0 and n_off[2] > 0 and n_off[3] == 0, (r, n_off)
        assert int(m["stagnant_species"][r]) == 1 and float(m["best_fitness"][r]) == 12.0
        # the records: species 1's is now its fitness 11 (not its score 2); species 0's and 2's are kept
        assert np.asarray(new.species_best)[r, :3].tolist() == [10.0, 11.0, 50.0]


def test_stagnation_on_the_fitness_alone_is_the_plain_step():
    """Without a separate fitness, the score is the fitness: the species of the top score is spared, a
    species whose score stalled below its record is culled."""
    state = tagged_state([8, 8, 8]).replace(
        generation=jnp.int32(20), species_best=jnp.full((CFG.species_capacity,), 10.0, jnp.float32),
        species_improved=jnp.zeros((CFG.species_capacity,), jnp.int32))
    sp = np.asarray(state.species)
    score = jnp.asarray(np.select([sp == 0, sp == 1], [9.0, 11.0], 5.0), jnp.float32)
    _, m = _tell(CFG)(jax.random.key(7), state.population, score, state, QUIET)
    n_off = np.asarray(m["offspring"])[:3]
    assert n_off[0] == 0 and n_off[1] > 0 and n_off[2] == 0, n_off
    assert int(m["stagnant_species"]) == 2


# ------------------------------------------------------------------------------------------ add-link cap


def test_the_add_link_cap_defaults_to_the_old_value_and_is_validated():
    for p in (2, 7, 24, 64, 150, 1000):
        cfg = NEATConfig(n_inputs=3, n_outputs=2, population_size=p, species_capacity=2)
        assert cfg.add_link_cap == min(p, max(8, p // 8))
    assert NEATConfig(n_inputs=3, n_outputs=2, population_size=24, max_add_links=5).add_link_cap == 5
    assert NEATConfig(n_inputs=3, n_outputs=2, population_size=24, max_add_links=24).add_link_cap == 24
    for bad in (-1, 25, 2.0, True):
        with pytest.raises(NEATError, match="max_add_links"):
            NEATConfig(n_inputs=3, n_outputs=2, population_size=24, max_add_links=bad)


@pytest.mark.slow  # ~12 s cold on an AVX2 CPU: the default suite's 7 minutes (make test-slow)
@pytest.mark.parametrize("cap", [3, 0])  # 0: the preset's cap (~7 s)
def test_add_link_draws_beyond_the_cap_are_skipped_and_counted(cap):
    config = NEATConfig(n_inputs=3, n_outputs=2, population_size=24, max_nodes=12, max_conns=40,
                        species_capacity=6, max_add_links=cap)
    limit = config.add_link_cap  # 3, or the default 8
    params = NEATParams(add_node_prob=0.0, add_link_prob=1.0, initial_link_fraction=0.3)
    pop = jax.vmap(lambda k: gn.initial_genome(k, config, params))(jax.random.split(jax.random.key(8), 24))
    frozen = jnp.arange(24) < 4  # 20 genomes draw add-link
    new, _, _, c = jax.jit(functools.partial(inn.mutate_population, config=config))(
        jax.random.key(9), pop, frozen, jnp.int32(config.n_fixed), jnp.int32(config.n_initial_conns), params)
    assert int(c.link_capped) == 20 - limit
    assert int(c.link_overflow) == 0 and int(c.link_exhausted) == 0  # a sparse genome always has a link to add
    grew = np.flatnonzero(np.asarray(new.conn_valid).sum(1) > np.asarray(pop.conn_valid).sum(1))
    assert grew.tolist() == list(range(4, 4 + limit))  # the first genomes to draw it, in population order
    # At add_link_prob 0.5 only some draw it: the draws are read from the keys mutate_population gives
    # each genome's structural mutation (the first of its five).
    half = params.replace(add_link_prob=0.5)
    drew = np.asarray(jax.vmap(lambda k: gn.structure_draw(k, half)[1])(
        jax.random.split(jax.random.key(9), (24, 5))[:, 0])) & ~np.asarray(frozen)
    _, _, _, c = jax.jit(functools.partial(inn.mutate_population, config=config))(
        jax.random.key(9), pop, frozen, jnp.int32(config.n_fixed), jnp.int32(config.n_initial_conns), half)
    assert 0 < drew.sum() - limit < 20 - limit
    assert int(c.link_capped) == drew.sum() - limit
    # through tell: every genome but the elites draws add-link
    state = _init(config)(jax.random.key(10), params)
    _, m = jax.jit(functools.partial(alg.tell, config=config))(jax.random.key(11), state.population,
                                                                jnp.arange(24.0), state, params)
    elites = int(np.sum((np.asarray(m["species_sizes"]) > params.elitism_min_size) & (np.asarray(m["offspring"]) > 0)))
    assert int(m["link_capped"]) == 24 - elites - limit



def test_the_fittest_genomes_children_are_counted():
    """``fittest_offspring`` counts the children the fittest genome (by task fitness) is a parent of, and
    ``fittest_elite`` whether it is copied unchanged; checked against the parents read from the weights."""
    sizes = [10, 9, 5]
    state = tagged_state(sizes)
    fitness = 1.0 + jax.random.permutation(jax.random.key(8), P).astype(jnp.float32) / P
    keys = jax.random.split(jax.random.key(9), KEYS)
    f = np.asarray(fitness)
    top = int(np.argmax(f))
    sp = np.asarray(state.species)
    elite_species = sizes[sp[top]] > QUIET.elitism_min_size
    # selection on the fitness: the fittest genome heads its species' pool
    new, m = _tell_keys()(keys, state.population, fitness, state, QUIET)
    for r in range(keys.shape[0]):
        carried = sum(top in par for par in parents_of(one(new.population, r)))
        assert int(m["fittest_offspring"][r]) == carried > 0
        assert int(m["fittest_elite"][r]) == int(elite_species)
    # selection on a score that ranks the fittest genome last: it is outside every pool and has no child
    score = jnp.asarray(f.max() + 1.0 - f)
    new, m = _tell_keys(True)(keys, state.population, score, state, QUIET, fitness)
    for r in range(keys.shape[0]):
        assert not any(top in par for par in parents_of(one(new.population, r)))
    assert np.all(np.asarray(m["fittest_offspring"]) == 0) and np.all(np.asarray(m["fittest_elite"]) == 0)
