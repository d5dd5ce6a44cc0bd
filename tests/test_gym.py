"""Keep-away as a gymnax-style environment (kx.sim.gym): the world's own rules and kick noise, SMDP steps
from one decision of the holder to the next, an episode's return equal to its fitness, jit and vmap."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.sim import env, gym, observe
from kx.sim import evaluate as ev
from kx.sim.policies import heuristic
from kx.sim.types import KeepAwayConfig, KeepAwayParams

CFG = KeepAwayConfig()  # 3v2
PARAMS = KeepAwayParams(kick_noise_deg=10.0)
ENV = gym.KeepAway(CFG)
RESET_BATCH = jax.jit(ENV.reset_batch, static_argnums=1)  # one program a batch size, not op by op


def _same(a, b):
    for f in a.__dataclass_fields__:
        np.testing.assert_array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)), err_msg=f)


def test_an_smdp_step_is_the_worlds_iterations_from_one_decision_to_the_next():
    key = jax.random.key(3)
    obs, state = ENV.reset(key, PARAMS)
    assert obs.shape == (ENV.observation_size,) == (13,)
    np.testing.assert_array_equal(obs, observe.fixed_obs(state.world, CFG))
    step = jax.jit(ENV.step_env)
    s_max = env.noise_limit(PARAMS.kick_noise_deg)
    world = state.world
    rng = np.random.default_rng(0)
    passes_seen, total = 0, 0.0
    iterate = jax.jit(lambda w, keeper, word: env.transition(w, keeper, env.kick_noise(word, w.t, s_max), PARAMS, CFG))
    order = jax.jit(lambda w: observe.teammate_order(w, CFG))
    for i in range(60):
        action = int(rng.integers(0, gym.N_ACTIONS))
        # the world by hand: the decision, then iterations with no decision while the ball flies
        keeper = order(world)[action]
        t0 = int(world.t)
        world = iterate(world, keeper, state.noise_word)
        while int(world.holder) < 0 and not bool(world.done):
            world = iterate(world, jnp.int32(-1), state.noise_word)
        before = state
        obs, state, reward, done, info = step(jax.random.key(i), state, jnp.int32(action), PARAMS)
        _same(state.world, world)
        assert int(info["iterations"]) == int(world.t) - t0 >= (0 if bool(before.world.done) else 1)
        assert bool(done) == bool(world.done)
        assert bool(done) or int(world.holder) >= 0  # a step ends at a decision, or at the episode's end
        lost = int(world.reason) in (1, 2, 3) and not bool(before.world.done)  # the losing iteration
        # does not count
        assert float(reward) * PARAMS.max_iterations == pytest.approx(int(world.t) - t0 - lost, abs=1e-3)
        passes_seen += int(info["iterations"]) > 1
        total += float(reward)
        if bool(done):
            # the return is the episode's fitness
            assert total == pytest.approx(float(env.episode_stats(world, PARAMS, CFG).fitness), abs=2e-6)
            _, after, reward_after, _, _ = step(jax.random.key(99), state, jnp.int32(0), PARAMS)
            _same(after.world, state.world)  # step_env leaves a finished episode as it is
            assert float(reward_after) == 0.0
            break
    assert bool(done) and passes_seen > 0  # random decisions lose the ball within 60 steps; some steps spanned a flight


def _heuristic_action(state):
    """The heuristic's keeper as an action of the ranked order (3v2: every keeper is in it)."""
    keeper = heuristic(CFG).apply(None, state.world, None)
    order = observe.teammate_order(state.world, CFG)
    return jnp.argmax(order == keeper).astype(jnp.int32)


@pytest.mark.slow  # ~30 s: whole episodes of the heuristic, through the evaluator and through the environment
def test_an_episodes_return_is_the_evaluators_fitness_for_the_same_decisions():
    trials = 6
    key = jax.random.key(11)
    starts = env.reset_batch(jax.random.key(5), trials, PARAMS, CFG)
    stats = ev.evaluate(heuristic(CFG), None, starts, PARAMS, CFG, key=key)
    words = env.noise_words(ev.stream_keys(key)[0], jnp.arange(trials))

    @jax.jit
    @jax.vmap
    def episode(start, word):
        def body(carry):
            s, total = carry
            _, s2, r, _, _ = ENV.step_env(jax.random.key(0), s, _heuristic_action(s), PARAMS)
            return s2, total + r

        final, total = jax.lax.while_loop(lambda c: ~c[0].world.done, body,
                                          (gym.EnvState(world=start, noise_word=word), jnp.float32(0.0)))
        return final.world, total

    finals, totals = episode(jax.tree.map(lambda a: jnp.moveaxis(a, -1, 0), starts), words)
    for i in range(trials):
        final = jax.tree.map(lambda a: a[i], finals)
        assert bool(final.done)
        assert int(final.t) == int(stats.iterations[0, i]) and int(final.reason) == int(stats.reason[0, i])
        assert int(final.passes) == int(stats.passes[0, i])
        assert float(totals[i]) == pytest.approx(float(stats.fitness[0, i]), abs=2e-6)
        assert float(gym.survived(final, PARAMS)) == float(stats.fitness[0, i])


@pytest.mark.slow  # ~15 s: the default suite vmaps the step in the gymnax training loop and checks the batched
# step against the per-episode one
def test_reset_and_step_vmap_over_episodes_as_one_by_one_and_step_starts_a_new_episode():
    keys = jax.random.split(jax.random.key(7), 8)
    _, states = jax.vmap(ENV.reset, in_axes=(0, None))(keys, PARAMS)
    actions = jnp.arange(8, dtype=jnp.int32) % gym.N_ACTIONS
    step = jax.jit(jax.vmap(ENV.step, in_axes=(0, 0, 0, None)))
    one_step = jax.jit(ENV.step)
    for _ in range(5):
        o2, s2, r, d, _ = step(keys, states, actions, PARAMS)
        for i in range(8):
            one = jax.tree.map(lambda a: a[i], states)
            oi, si, ri, di, _ = one_step(keys[i], one, actions[i], PARAMS)  # one episode
            np.testing.assert_allclose(o2[i], oi, rtol=1e-6)  # float features: batched they may round apart
            # in the last bit; the world's integer state is exact
            _same(jax.tree.map(lambda a: a[i], s2).world, si.world)
            assert float(r[i]) == float(ri) and bool(d[i]) == bool(di)
        states = s2
    # a finished episode is replaced by reset(key)'s
    short = KeepAwayParams(kick_noise_deg=10.0, max_iterations=3)
    _, s = ENV.reset(keys[0], short)
    for _ in range(3):
        _, s, _, done, _ = one_step(keys[1], s, jnp.int32(0), short)
        if bool(done):
            break
    assert bool(done)
    _same(s.world, ENV.reset(keys[1], short)[1].world)


def test_the_batched_step_is_the_per_episode_step_with_the_same_decisions():
    """``reset_batch``/``step_batch_env`` (batch-last, for training) give the worlds, rewards and
    observations that the per-episode ``reset``/``step_env`` give episode by episode, whatever the
    other episodes of the batch do (some fly a pass for several iterations while others hold)."""
    n = 12
    key = jax.random.key(21)
    obs_b, batch = RESET_BATCH(key, n, PARAMS)
    keys = jax.random.split(key, n)
    obs_1, states = jax.jit(jax.vmap(ENV.reset, in_axes=(0, None)))(keys, PARAMS)
    np.testing.assert_array_equal(obs_b, obs_1)
    step_b = jax.jit(ENV.step_batch_env)
    step_1 = jax.jit(ENV.step_env)
    rng = np.random.default_rng(4)
    flights = ended = 0
    for _ in range(30):
        actions = jnp.asarray(rng.integers(0, gym.N_ACTIONS, n), jnp.int32)
        obs_b, batch, r_b, d_b, info = step_b(batch, actions, PARAMS)
        flights += int((info["iterations"] > 1).sum())
        for i in range(n):
            one = jax.tree.map(lambda a: a[i], states)
            o, s, r, d, _ = step_1(keys[i], one, actions[i], PARAMS)
            _same(jax.tree.map(lambda a: a[..., i], batch.world), s.world)
            assert bool(d_b[i]) == bool(d)
            # the float reward and features, batched, may round apart in the last bit (a vectorised
            # division); the world's integer state is exact
            assert float(r_b[i]) == pytest.approx(float(r), abs=2.5e-7)  # a float32 ulp of the shares survived
            np.testing.assert_allclose(obs_b[i], o, rtol=1e-6)
            states = jax.tree.map(lambda a, b: a.at[i].set(b), states, s)
    ended = int(d_b.sum())
    assert flights > 10 and ended > 0


def test_the_batched_step_gives_ended_episodes_the_drawn_starts_in_order():
    short = KeepAwayParams(kick_noise_deg=10.0, max_iterations=2)
    n, resets = 6, 4
    _, batch = RESET_BATCH(jax.random.key(0), n, short)
    key = jax.random.key(5)
    # every episode ends at its second iteration: all six at once, more than the four starts drawn
    step = jax.jit(ENV.step_batch, static_argnums=4)
    for _ in range(2):
        _, batch, _, done, info = step(key, batch, jnp.zeros(n, jnp.int32), short, resets)
    assert bool(done.all()) and int(info["shared_starts"]) == n - resets
    k_starts, _ = jax.random.split(key)
    _, fresh = RESET_BATCH(k_starts, resets, short)
    for i in range(n):  # the i-th episode to end takes start i (mod resets), with a noise word of its own
        _same(jax.tree.map(lambda a: a[..., i], batch.world), jax.tree.map(lambda a: a[..., i % resets], fresh.world))
        assert int(batch.world.t[i]) == 0 and not bool(batch.world.done[i])
    words = np.asarray(batch.noise_word)
    assert len(set(words.tolist())) == n


@pytest.mark.slow  # ~12 s cold: the suite's 7 minutes on an AVX2 CPU
def test_iterating_one_world_iteration_at_a_time_plays_the_smdp_steps():
    """``iterate_batch`` (one world iteration of every episode; those at a decision act) and ``land_batch``
    (the passes in flight land) play the episodes ``step_batch_env`` plays with the same decisions: the same
    worlds at every decision, each SMDP step's reward the sum of its iterations' and its end at the same
    step, however the batch's episodes interleave their passes."""
    n, steps = 10, 25
    _, start = RESET_BATCH(jax.random.key(8), n, PARAMS)
    step = jax.jit(ENV.step_batch_env)
    iterate = jax.jit(ENV.iterate_batch, static_argnums=4)
    land = jax.jit(ENV.land_batch, static_argnums=3)
    rng = np.random.default_rng(9)
    plan = np.where(rng.random((steps, n)) < 0.8, 0, rng.integers(1, gym.N_ACTIONS, (steps, n)))
    worlds, rewards, ends = [], [], np.full(n, steps)
    batch = start
    for k in range(steps):
        _, batch, r, d, _ = step(batch, jnp.asarray(plan[k], jnp.int32), PARAMS)
        worlds.append(batch.world)
        rewards.append(np.asarray(r))
        ends = np.where(np.asarray(d) & (ends == steps), k, ends)
    last = np.minimum(ends, steps - 1)  # each episode's last SMDP step compared
    assert (ends < steps).any() and ends.max() > 5
    batch, made, acc = start, np.zeros(n, int), np.zeros(n)
    finished = np.zeros(n, bool)
    flying_seen = ended = 0
    key = jax.random.key(0)
    while not finished.all():
        deciding = np.asarray(ENV.deciding(batch))
        flying_seen += int((~deciding & ~finished).sum())
        action = jnp.asarray(plan[np.minimum(made, steps - 1), np.arange(n)], jnp.int32)
        _, nxt, r, d, info = iterate(key, batch, action, PARAMS, 4)
        assert bool((info["iterations"] == 1).all())
        acc += np.where(finished, 0.0, np.asarray(r))
        made += deciding & ~finished
        now = np.asarray(ENV.deciding(nxt))
        for i in np.flatnonzero(~finished):
            if bool(d[i]):  # the episode ended at the SMDP step where step_batch_env's did
                assert made[i] - 1 == ends[i]
                assert acc[i] == pytest.approx(rewards[ends[i]][i], abs=1e-6)
                finished[i], ended = True, ended + 1
            elif now[i]:  # a decision reached: the world after SMDP step made - 1
                k = made[i] - 1
                _same(jax.tree.map(lambda a: a[..., i], nxt.world), jax.tree.map(lambda a: a[..., i], worlds[k]))
                assert acc[i] == pytest.approx(rewards[k][i], abs=1e-6)
                acc[i] = 0.0
                finished[i] = k == last[i]
        batch = nxt
    assert flying_seen > 20 and ended > 0  # passes flew while other episodes decided; some episodes ended
    # landing from mid-flight: every episode at a decision afterwards, after iterations of its own
    mid = iterate(key, start, jnp.ones(n, jnp.int32), PARAMS, 4)[1]  # every episode passes
    assert int((~ENV.deciding(mid)).sum()) >= n // 2  # (a pass to a teammate on the holder's cell lands at once)
    _, landed, r, d, info = land(key, mid, PARAMS, 4)
    assert bool(ENV.deciding(landed).all())
    its = np.asarray(info["iterations"])
    waiting = np.asarray(ENV.deciding(mid))
    assert (its[waiting] == 0).all() and (its[~waiting] >= 1).all() and len(set(its[~waiting].tolist())) > 1


@pytest.mark.slow  # ~21 s cold: the batched step's equality to the per-episode one stays in the default suite
def test_a_training_loop_written_for_gymnax_runs_on_it_unchanged():
    """A small policy-gradient loop written against gymnax's interface alone (no kx call but the constructor):
    ``default_params``, ``action_space``/``observation_space``, ``reset`` and ``step`` vmapped, auto-reset,
    ``info["iterations"]`` for the SMDP discount. Its observations lie in the space, its episodes restart once
    ended, the parameters move, and an episode's rewards add up to its fitness; a time limit reads as
    truncated, not terminated."""
    import optax

    short = KeepAwayParams(kick_noise_deg=10.0, max_iterations=60)
    envx = gym.KeepAway(CFG)
    params = envx.default_params.replace(max_iterations=short.max_iterations)
    assert int(params.max_steps_in_episode) == 60 and envx.name == "KeepAway-3v2"
    act_space, obs_space = envx.action_space(params), envx.observation_space(params)
    n, steps, gamma = 16, 30, 0.99
    reset = jax.jit(jax.vmap(envx.reset, in_axes=(0, None)))
    step = jax.vmap(envx.step, in_axes=(0, 0, 0, None))
    obs, state = reset(jax.random.split(jax.random.key(0), n), params)
    w = jnp.zeros((obs_space.shape[0], act_space.n))
    opt = optax.adam(0.05)
    opt_state = opt.init(w)

    @jax.jit
    def rollout(w, obs, state, key):
        def body(carry, k):
            obs, state = carry
            k_act, k_env = jax.random.split(k)
            a = jax.random.categorical(k_act, obs @ w)
            obs2, state2, r, done, info = step(jax.random.split(k_env, n), state, a, params)
            return (obs2, state2), (obs, a, r, done, info["iterations"], info["truncated"], state2.world.t)
        return jax.lax.scan(body, (obs, state), jax.random.split(key, steps))

    def loss(w, o, a, g):
        logp = jax.nn.log_softmax(o @ w)
        return -(jnp.take_along_axis(logp, a[..., None], -1)[..., 0] * g).mean()

    ended = truncated = 0
    for u in range(3):
        (obs, state), (o, a, r, d, its, trunc, t_next) = rollout(w, obs, state, jax.random.key(10 + u))
        assert bool(jax.vmap(jax.vmap(obs_space.contains))(o).all()) and bool(act_space.contains(a).all())
        # after an end the next state is a fresh episode's (auto-reset)
        assert bool((jnp.where(d, t_next, 0) == 0).all())
        ended += int(d.sum())
        truncated += int(trunc.sum())

        def back(g, x):  # discounted returns to go, a step discounted by gamma ** its iterations
            r_t, d_t, it = x
            g = r_t + jnp.where(d_t, 0.0, gamma ** it.astype(jnp.float32) * g)
            return g, g

        _, g = jax.lax.scan(back, jnp.zeros(n), (r * 100, d, its), reverse=True)
        grads = jax.grad(loss)(w, o, a, g - g.mean())
        upd, opt_state = opt.update(grads, opt_state)
        w = optax.apply_updates(w, upd)
    assert ended > 0 and truncated > 0 and bool(jnp.isfinite(w).all()) and float(jnp.abs(w).sum()) > 0
    # one episode without auto-reset: its rewards add up to its fitness
    o1, s1 = envx.reset(jax.random.key(5), params)
    step1 = jax.jit(envx.step_env)
    total, done, info = 0.0, False, {}
    while not done:
        o1, s1, r1, d1, info = step1(jax.random.key(0), s1, jnp.int32(0), params)
        total, done = total + float(r1), bool(d1)
    assert total == pytest.approx(float(env.episode_stats(s1.world, params, CFG).fitness), abs=1e-6)
    assert bool(info["terminated"]) != bool(info["truncated"]) and float(info["discount"]) == 0.0
