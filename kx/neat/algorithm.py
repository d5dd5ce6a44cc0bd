"""NEAT's generation step as pure functions: ``init``, ``ask``, ``tell`` (the evosax shape).

Stanley & Miikkulainen (2002), with the choices of ``SPEC.md`` §2::

    state = init(key, params, config)
    for generation in range(n):
        population, state = ask(key_ask, state, params, config)     # Genome pytree, [P, ...]
        fitness = my_fitness(build_networks(population))            # [P] float, higher is better
        state, metrics = tell(key_tell, population, fitness, state, params, config)
        # or: select on another score (a novelty hybrid, say) and report the task fitness
        # state, metrics = tell(key_tell, population, score, state, params, config, fitness=fitness)

``tell`` is the whole generation step: species bookkeeping and stagnation, explicit fitness sharing,
offspring allocation, selection within the top ``survival_threshold`` of each species, champion
elitism, crossover and mutation with innovation numbers shared across the generation, speciation of the
offspring against representatives of the previous species, and adaptation of the compatibility
threshold toward ``target_species``. It is a function of fixed-shape arrays with no Python loop over
genomes or species (new species are founded in a ``lax.while_loop`` that runs once per new species), so
it compiles once and vmaps over seeds.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from kx.neat import genome as gn
from kx.neat import innovation as inn
from kx.neat.network import Network, build, hidden_rows, trim
from kx.neat.types import HIDDEN, Genome, NEATConfig, NEATError, NEATParams, NEATState

I32, F32 = jnp.int32, jnp.float32


def _take(tree, idx):
    return jax.tree.map(lambda x: x[idx], tree)


def _pairwise(pop: Genome, reps: Genome, params: NEATParams) -> jax.Array:
    """``[P, S]`` compatibility distances."""
    sp, sr = jax.vmap(gn.distance_stats)(pop), jax.vmap(gn.distance_stats)(reps)
    return jax.vmap(lambda g, s_g: jax.vmap(lambda r, s_r: gn.distance(g, r, params, s_g, s_r))(reps, sr))(pop, sp)


def speciate(pop: Genome, reps: Genome, rep_alive: jax.Array, threshold: jax.Array, params: NEATParams):
    """Assign each genome a species slot.

    A genome joins the nearest living species whose representative, a member of the previous
    generation, is closer than ``threshold``. Genomes left over found new
    species in free slots, in population order: the first left over becomes the representative, and
    every left-over genome closer than ``threshold`` to it joins it (Stanley's sequential rule, one
    loop iteration per new species). No species is founded once ``params.target_species`` exist (the
    paper's "maximum number of species") or the slots are full: the rest join their nearest species
    and are counted as overflow, which raises the threshold (see :func:`tell`).

    Returns ``(species [P], alive [S], founded [S], overflow)``; ``founded`` marks new species.
    """
    p, s = pop.node_id.shape[0], rep_alive.shape[0]
    d = _pairwise(pop, reps, params)
    cand = rep_alive[None, :] & (d < threshold)
    species = jnp.where(jnp.any(cand, axis=1), jnp.argmin(jnp.where(cand, d, jnp.inf), axis=1), -1).astype(I32)

    def cond(c):
        species, alive, _, _ = c
        return jnp.any(species < 0) & (jnp.sum(alive) < params.target_species) & jnp.any(~alive)

    def body(c):
        species, alive, founded, d = c
        g = jnp.argmax(species < 0)
        slot = jnp.argmax(~alive)
        dg = jax.vmap(lambda x: gn.distance(x, _take(pop, g), params))(pop)
        join = (species < 0) & ((dg < threshold) | (jnp.arange(p) == g))
        return (jnp.where(join, slot, species).astype(I32), alive.at[slot].set(True),
                founded.at[slot].set(True), d.at[:, slot].set(dg))

    species, alive, founded, d = jax.lax.while_loop(cond, body, (species, rep_alive, jnp.zeros((s,), bool), d))
    # Left over with no slot to found: the nearest species (founders' columns of d are theirs now).
    left = species < 0
    near = jnp.argmin(jnp.where(alive[None, :], d, jnp.inf), axis=1).astype(I32)
    species = jnp.where(left, near, species)
    counts = jax.ops.segment_sum(jnp.ones((p,), I32), species, s)
    alive = counts > 0
    return species, alive, founded & alive, jnp.sum(left, dtype=I32)


def allocate(share: jax.Array, eligible: jax.Array, total: int, cap: jax.Array) -> jax.Array:
    """Offspring per species ``[S]`` (int32, summing to ``total``), proportional to ``share`` among
    ``eligible`` species, at most ``cap`` each (0: no cap; raised to ``ceil(total / eligible)`` when
    the cap could not place everyone): capped shares are fixed and the rest re-divided until none
    exceeds the cap, then rounded by largest remainder."""
    s = share.shape[0]
    n_el = jnp.maximum(jnp.sum(eligible), 1)
    cap = jnp.where(cap > 0, jnp.maximum(cap, -(-total // n_el)), total).astype(F32)
    share = jnp.where(eligible, share, 0.0)

    def quotas(capped):
        free = eligible & ~capped
        rest = total - cap * jnp.sum(capped)
        tot = jnp.sum(jnp.where(free, share, 0.0))
        n_free = jnp.maximum(jnp.sum(free), 1)
        q = jnp.where(tot > 0, share / jnp.where(tot > 0, tot, 1.0), 1.0 / n_free) * rest
        return jnp.where(capped, cap, jnp.where(free, q, 0.0))

    capped = jax.lax.fori_loop(0, s, lambda _, c: c | (quotas(c) > cap), jnp.zeros((s,), bool))
    q = quotas(capped)
    base = jnp.floor(q).astype(I32)
    rem = total - jnp.sum(base)
    frac = jnp.where(eligible, q - base, -1.0)
    rank = jnp.argsort(jnp.argsort(-frac, stable=True), stable=True)
    return base + (rank < rem).astype(I32)


def init(key: jax.Array, params: NEATParams, config: NEATConfig) -> NEATState:
    """The first population: every genome fully connected, weights at random; speciated."""
    pop = jax.vmap(lambda k: gn.initial_genome(k, config, params))(jax.random.split(key, config.population_size))
    return init_from(pop, config.n_fixed, config.n_initial_conns, params.compat_threshold, params, config)


def init_from(population: Genome, next_node_id: jax.Array, next_innov: jax.Array, threshold: jax.Array,
              params: NEATParams, config: NEATConfig) -> NEATState:
    """A first state whose population is given (a transferred or seeded one, ``[P, ...]`` in
    ``config``'s shapes): speciated from scratch at ``threshold`` (its first genome founds the first
    species, as in :func:`init`), the innovation counters carried on, no species history and no best
    genome yet."""
    s = config.species_capacity
    threshold = jnp.asarray(threshold, F32)
    reps = _take(population, jnp.zeros((s,), I32))
    species, alive, founded, _ = speciate(population, reps, jnp.zeros((s,), bool), threshold, params)
    uid = jnp.where(founded, jnp.cumsum(founded) - 1, -1).astype(I32)
    return NEATState(
        population=population, species=species, species_alive=alive, species_uid=uid,
        species_best=jnp.full((s,), -jnp.inf, F32), species_improved=jnp.zeros((s,), I32), threshold=threshold,
        next_node_id=jnp.asarray(next_node_id, I32), next_innov=jnp.asarray(next_innov, I32),
        next_species_uid=jnp.sum(founded, dtype=I32), generation=jnp.zeros((), I32),
        best_genome=_take(population, 0), best_fitness=jnp.asarray(-jnp.inf, F32))


def seed_copies(key: jax.Array, genomes: Genome, next_node_id: jax.Array, next_innov: jax.Array,
                params: NEATParams, config: NEATConfig) -> tuple[Genome, jax.Array, jax.Array]:
    """A population of ``config.population_size`` genomes seeded by the ``M`` given ones (``[M, ...]``,
    ``M <= population_size``): genome ``i < M`` is ``genomes[i]`` unchanged, genome ``i >= M`` a copy of
    ``genomes[i % M]`` mutated once, as an offspring is (:func:`kx.neat.innovation.mutate_population`,
    innovation numbers shared across the population). Returns ``(population, next_node_id, next_innov)``."""
    p = config.population_size
    m = jax.tree.leaves(genomes)[0].shape[0]
    if not 1 <= m <= p:
        raise NEATError(f"seed_copies: {m} seed genomes for a population of {p}: allowed 1..{p}")
    idx = jnp.arange(p, dtype=I32)
    base = _take(genomes, idx % m)
    pop, next_node_id, next_innov, _ = inn.mutate_population(key, base, idx < m, jnp.asarray(next_node_id, I32),
                                                             jnp.asarray(next_innov, I32), params, config)
    return pop, next_node_id, next_innov


def ask(key: jax.Array, state: NEATState, params: NEATParams, config: NEATConfig) -> tuple[Genome, NEATState]:
    """The population to evaluate (reproduction happens in :func:`tell`; ``key`` is unused)."""
    del key, params, config
    return state.population, state


def build_networks(population: Genome, config: NEATConfig) -> Network:
    """Networks of a whole population (``[P, ...]`` leaves)."""
    return jax.vmap(lambda g: build(g, config))(population)


def policy_networks(population: Genome, rows: int, config: NEATConfig) -> Network:
    """The networks of genomes with any leading axes (a population ``[P]``, a group's ``[R, P]``), with
    ``rows`` hidden rows (:func:`kx.neat.network.trim`)."""
    lead = population.node_kind.shape[:-1]
    flat = jax.tree.map(lambda a: a.reshape((int(np.prod(lead)),) + a.shape[len(lead):]), population)
    nets = trim(build_networks(flat, config), rows, config)
    return jax.tree.map(lambda a: a.reshape(lead + a.shape[1:]), nets)


def _finite(x: jax.Array) -> jax.Array:
    """``[P]`` float32 with non-finite values replaced by the worst finite one (0 if none is finite)."""
    x = jnp.asarray(x, F32)
    ok = jnp.isfinite(x)
    x = jnp.where(ok, x, jnp.min(jnp.where(ok, x, jnp.inf)))
    return jnp.where(jnp.any(ok), x, 0.0)


def tell(key: jax.Array, population: Genome, score: jax.Array, state: NEATState, params: NEATParams,
         config: NEATConfig, fitness: jax.Array | None = None) -> tuple[NEATState, dict]:
    """Select on ``score`` ``[P]`` of the evaluated ``population`` and breed the next generation.

    ``score`` is what the learner selects on: explicit fitness sharing, offspring allocation, parent
    ranking within the survival threshold and elitism. ``fitness`` ``[P]`` (default: ``score``) is the
    task fitness: it decides stagnation (``state.species_best`` holds each species' best task fitness,
    a quantity comparable across generations, where a score normalised per generation, like the
    novelty hybrid's, is not), ``state.best_genome``/``best_fitness`` and every fitness metric
    (``best_fitness``, ``mean_fitness``, ``median_fitness``; ``champion_hidden``/``champion_links``
    describe the fittest genome). Neither the species of the top score nor that of the fittest genome
    is ever stagnant. With ``fitness=None`` this is the plain NEAT step on ``score``.

    In both, non-finite values count as the population's worst finite value. Returns the new state and
    this generation's metrics (scalars and ``[S]`` arrays, about the evaluated population).
    """
    p, s = config.population_size, config.species_capacity
    gen = state.generation
    sc = _finite(score)  # what selection sees
    f = sc if fitness is None else _finite(fitness)  # what is reported, and the best genome
    sp = state.species
    k_par, k_mut, k_rep, k_x = jax.random.split(key, 4)

    # Species bookkeeping: improvement and stagnation, on the task fitness (comparable across
    # generations; a normalised score is redrawn on [0, 1] every generation, so a record set in it is
    # rarely beaten again: docs/neat.md, "Stagnation").
    counts = jax.ops.segment_sum(jnp.ones((p,), I32), sp, s)
    sp_max = jax.ops.segment_max(f, sp, s)
    improved = state.species_alive & (sp_max > state.species_best)
    sp_best = jnp.where(improved, sp_max, state.species_best)
    sp_improved = jnp.where(improved, gen, state.species_improved)
    champ = jnp.argmax(f)  # the fittest genome (top, when fitness is the score)
    top = jnp.argmax(sc)  # the species of the best score and of the fittest genome are never stagnant
    slots = jnp.arange(s)
    stagnant = (gen - sp_improved >= params.stagnation_limit) & (slots != sp[top]) & (slots != sp[champ])
    eligible = state.species_alive & (counts > 0) & ~stagnant

    # Explicit fitness sharing: a species' share is the sum of its members' f / |species|.
    fs = sc - jnp.minimum(0.0, jnp.min(sc))
    share = jax.ops.segment_sum(fs, sp, s) / jnp.maximum(counts, 1)
    n_off = allocate(share, eligible, p, jnp.asarray(params.max_species_population, I32))

    # Parents: members sorted by species, then score (descending).
    order = jnp.lexsort((-sc, sp)).astype(I32)
    mem_start = jnp.cumsum(counts) - counts
    pool = jnp.clip(jnp.floor(params.survival_threshold * counts).astype(I32) + 1, 1, jnp.maximum(counts, 1))
    off_end = jnp.cumsum(n_off)
    child_sp = jnp.searchsorted(off_end, jnp.arange(p), side="right").astype(I32)
    rank = jnp.arange(p) - (off_end - n_off)[child_sp]
    elite = (rank == 0) & (counts[child_sp] > params.elitism_min_size)
    ks = jax.random.split(k_par, 6)
    u = jax.random.uniform(ks[0], (p, 2))
    pick = lambda k, sp_: order[mem_start[sp_] + jax.random.randint(k, (p,), 0, pool[sp_])]
    p1 = pick(ks[1], child_sp)
    other_sp = jax.random.categorical(ks[2], jnp.where(eligible & (counts > 0), 0.0, -jnp.inf), shape=(p,)).astype(I32)
    p2 = jnp.where(u[:, 1] < params.interspecies_prob, pick(ks[3], other_sp), pick(ks[4], child_sp))
    fitter = jnp.where(sc[p2] > sc[p1], p2, p1)
    weaker = jnp.where(sc[p2] > sc[p1], p1, p2)
    crossed = jax.vmap(lambda k, a, b: gn.crossover(k, a, b, params, config.genes))(
        jax.random.split(k_x, p), _take(population, fitter), _take(population, weaker))
    mut_only = u[:, 0] < params.mutation_only_prob
    base_idx = jnp.where(elite, order[mem_start[child_sp]], p1)
    base = jax.tree.map(lambda a, c: jnp.where((elite | mut_only).reshape((p,) + (1,) * (a.ndim - 1)), a, c),
                        _take(population, base_idx), crossed)
    children, next_node, next_innov, counters = inn.mutate_population(
        k_mut, base, elite, state.next_node_id, state.next_innov, params, config)

    # Speciate the offspring against a random member of each species that reproduced.
    rep_idx = order[mem_start + jax.random.randint(k_rep, (s,), 0, jnp.maximum(counts, 1))]
    rep_alive = state.species_alive & (n_off > 0)
    reps = _take(population, rep_idx)
    first = speciate(children, reps, rep_alive, state.threshold, params)

    # Species removed at once (stagnation, no offspring) can leave far fewer than the target; then,
    # if asked, speciate again with the threshold halved (up to ``respeciate`` times).
    def short(c):
        k, _, res = c
        return (k < params.respeciate) & (jnp.sum(res[1]) < params.target_species - 2)

    def again(c):
        k, thr, _ = c
        return k + 1, thr * 0.5, speciate(children, reps, rep_alive, thr * 0.5, params)

    _, used_threshold, (new_sp, alive, founded, sp_over) = jax.lax.while_loop(
        short, again, (jnp.zeros((), I32), state.threshold, first))
    uid = jnp.where(founded, state.next_species_uid + jnp.cumsum(founded) - 1, state.species_uid).astype(I32)
    n_species = jnp.sum(alive, dtype=I32)
    # Fewer species than the target: lower the threshold; genomes that fit no species and could not
    # found one: raise it. Multiplicative, so that it moves as fast at 0.2 as at 3.
    factor = jnp.where(n_species < params.target_species, 1.0 - params.threshold_step,
                       jnp.where(sp_over > 0, 1.0 + params.threshold_step, 1.0))
    threshold = jnp.maximum(used_threshold * factor, params.threshold_min)

    # Whether the fittest genome breeds: the children it is a parent of (its elite copy, a mutated copy or
    # either side of a crossover). Under a score other than fitness (the novelty hybrid's) it need not be
    # an elite, nor even in its species' parent pool.
    crossed_child = ~(elite | mut_only)
    from_fittest = (base_idx == champ) | (crossed_child & ((fitter == champ) | (weaker == champ)))
    better = f[champ] > state.best_fitness
    best_genome = jax.tree.map(lambda a, b: jnp.where(better, a, b), _take(population, champ), state.best_genome)
    new_state = NEATState(
        population=children, species=new_sp, species_alive=alive, species_uid=uid,
        species_best=jnp.where(founded, -jnp.inf, sp_best),
        species_improved=jnp.where(founded, gen + 1, sp_improved),
        threshold=threshold,
        next_node_id=next_node, next_innov=next_innov,
        next_species_uid=state.next_species_uid + jnp.sum(founded, dtype=I32),
        generation=gen + 1, best_genome=best_genome, best_fitness=jnp.maximum(f[champ], state.best_fitness))
    metrics = {
        "generation": gen,
        "best_fitness": f[champ],
        # float32 rounding can put the mean of equal values a hair above them: clip to where it lies
        "mean_fitness": jnp.clip(jnp.mean(f), jnp.min(f), f[champ]),
        "median_fitness": jnp.median(f),
        "n_species": jnp.sum(state.species_alive & (counts > 0), dtype=I32),
        "n_species_next": n_species,
        "threshold": state.threshold,
        "mean_hidden": jnp.mean(jnp.sum(population.node_kind == HIDDEN, axis=1).astype(F32)),
        "mean_links": jnp.mean(jnp.sum(population.conn_valid & population.conn_enabled, axis=1).astype(F32)),
        "champion_hidden": jnp.sum(population.node_kind[champ] == HIDDEN, dtype=I32),
        "champion_links": jnp.sum(population.conn_valid[champ] & population.conn_enabled[champ], dtype=I32),
        "stagnant_species": jnp.sum(stagnant & state.species_alive & (counts > 0), dtype=I32),  # culled now
        "species_sizes": counts,  # [S] by slot
        "species_ids": jnp.where(state.species_alive & (counts > 0), state.species_uid, -1),  # [S] run-wide ids
        "offspring": n_off,
        "node_overflow": counters.node_overflow,
        "link_overflow": counters.link_overflow,
        "link_exhausted": counters.link_exhausted,
        "link_capped": counters.link_capped,
        "species_overflow": sp_over,
        "new_nodes": counters.new_nodes,
        "new_links": counters.new_links,
        "fittest_offspring": jnp.sum(from_fittest, dtype=I32),  # children of the fittest genome
        "fittest_elite": jnp.any(elite & (base_idx == champ)).astype(I32),  # copied unchanged
    }
    return new_state, metrics


def validate(config: NEATConfig, params: NEATParams) -> None:
    """Check concrete parameters against the config; raises :class:`NEATError` naming the field."""
    params.validate()
    if int(params.target_species) > config.species_capacity:
        raise NEATError(f"NEATParams.target_species = {params.target_species}: allowed at most "
                        f"NEATConfig.species_capacity = {config.species_capacity}")


# One compiled program per static config, shared by every NEAT instance of the process: a second run
# of the same shapes compiles nothing (its seed and parameters are traced).
_init_jit = jax.jit(init, static_argnames=("config",))
_tell_jit = jax.jit(tell, static_argnames=("config",))
_build_jit = jax.jit(build_networks, static_argnames=("config",))


@functools.lru_cache(maxsize=None)
def _policy_networks_jit(rows: int):
    """:func:`policy_networks` with ``rows`` hidden rows, compiled per config: one program per row count,
    named for it (a compilation log tells them apart; they are different programs, not recompilations)."""
    def fn(population, config):
        return policy_networks(population, rows, config)

    fn.__name__ = fn.__qualname__ = f"policy_networks_{rows}_hidden_rows"
    return jax.jit(fn, static_argnames=("config",))
_init_from_jit = jax.jit(init_from, static_argnames=("config",))
_seed_copies_jit = jax.jit(seed_copies, static_argnames=("config",))


class NEAT:
    """NEAT for one :class:`NEATConfig`, with jitted ``init``/``ask``/``tell`` (evosax's interface)::

        neat = NEAT(config)
        state = neat.init(key)
        population, state = neat.ask(k1, state)
        state, metrics = neat.tell(k2, population, fitness, state)
        # or neat.tell(k2, population, score, state, fitness=fitness): see :func:`tell`

    The compiled programs are the module's, keyed by the (hashable, static) config: every instance with
    an equal config shares them, and parameters, keys and populations are traced arguments.
    """

    def __init__(self, config: NEATConfig, params: NEATParams | None = None):
        self.config = config
        self.default_params = params if params is not None else NEATParams()
        validate(config, self.default_params)

    def init(self, key: jax.Array, params: NEATParams | None = None) -> NEATState:
        return _init_jit(key, params or self.default_params, config=self.config)

    def ask(self, key: jax.Array, state: NEATState, params: NEATParams | None = None):
        return ask(key, state, params or self.default_params, self.config)

    def tell(self, key, population, score, state, params: NEATParams | None = None, fitness=None):
        for name, x in (("score", score), ("fitness", fitness)):
            shape = getattr(x, "shape", None)
            if (x is not None or name == "score") and shape != (self.config.population_size,):
                raise NEATError(f"{name} has shape {shape}: expected ({self.config.population_size},), one value "
                                "per genome of the population")
        return _tell_jit(key, population, score, state, params or self.default_params, config=self.config,
                         fitness=fitness)

    def networks(self, population: Genome) -> Network:
        return _build_jit(population, config=self.config)

    def policy_networks(self, population: Genome) -> Network:
        """The networks the evaluator plays, of genomes with any leading axes: those of
        :meth:`networks`, but with only as many hidden rows as the genomes' most hidden nodes need
        (:func:`kx.neat.network.hidden_rows`, :func:`kx.neat.network.trim`): the same decisions, for a
        fraction of the cost while the population has few hidden nodes. The count is read on the host
        (the genomes' node kinds), so this is not traced: call it outside ``jit`` and ``vmap``."""
        kinds = np.asarray(population.node_kind)
        used = int((kinds == HIDDEN).sum(axis=-1).max()) if kinds.size else 0
        rows = hidden_rows(used, self.config.n_hidden)
        return _policy_networks_jit(rows)(population, config=self.config)

    def hidden_rows_of(self, populations: Genome) -> np.ndarray:
        """The hidden rows :meth:`policy_networks` keeps for each population of ``populations`` (``[R, P,
        ...]``): ``[R]`` host ints."""
        kinds = np.asarray(populations.node_kind)
        used = (kinds == HIDDEN).sum(axis=-1).reshape(kinds.shape[0], -1).max(axis=1)
        return np.array([hidden_rows(int(u), self.config.n_hidden) for u in used])

    def init_from(self, population: Genome, next_node_id, next_innov, threshold=None,
                  params: NEATParams | None = None) -> NEATState:
        """:func:`init_from` (``threshold`` default: the parameters' ``compat_threshold``)."""
        params = params or self.default_params
        threshold = params.compat_threshold if threshold is None else threshold
        return _init_from_jit(population, next_node_id, next_innov, threshold, params, config=self.config)

    def seed_copies(self, key, genomes: Genome, next_node_id, next_innov, params: NEATParams | None = None):
        """:func:`seed_copies` with this learner's config."""
        m = jax.tree.leaves(genomes)[0].shape[0]
        if not 1 <= m <= self.config.population_size:
            raise NEATError(f"seed_copies: {m} seed genomes for a population of {self.config.population_size}")
        return _seed_copies_jit(key, genomes, next_node_id, next_innov, params or self.default_params,
                                config=self.config)
