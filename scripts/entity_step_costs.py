"""What one decision costs the entity network against the MLP, part by part, in one process (the figures of
docs/benchmarks.md, `ppo`, "Where it goes"): ``python scripts/entity_step_costs.py [TASK]`` (default 4v3).

For each network (the MLP on the fixed inputs, 2 x 32 units; the entity network, 32 units, 4 heads, one block),
on 512 episodes' start states: its forward pass, the environment's iteration with its observation, the
observation alone, and one PPO minibatch step (loss, gradient, Adam) on 512 entries; each the median of 7 calls
of 16 steps, in microseconds an entry.

``--attention`` times instead the entity network's forward pass and minibatch step with three cores of its
self-attention, the projections and everything else the same: flax's (``dot_product_attention``: batched products
of small matrices, what the network computes), the same scores and mixing written as elementwise products and
sums (what a rewrite could gain; equal to flax's up to rounding, checked here), and no mixing at all (each token
its own value: what a network without attention, such as a pooling one, would cost at most)."""

import argparse
import contextlib
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

from kx.evolve.encodings.ppo import algorithm as A
from kx.sim import gym
from kx.sim.types import KeepAwayConfig, KeepAwayParams

N = 512


def timeit(name, body, carry):
    f = jax.jit(lambda c, k: jax.lax.scan(body, c, jax.random.split(k, 16)))
    jax.block_until_ready(f(carry, jax.random.key(1)))
    ts = []
    for i in range(7):
        t = time.perf_counter()
        jax.block_until_ready(f(carry, jax.random.key(i)))
        ts.append(time.perf_counter() - t)
    print(f"{name}: {np.median(ts) / 16 / N * 1e6:.3f} us an entry", flush=True)


def elementwise_attention(query, key, value, bias=None, mask=None, **_):
    """flax's ``dot_product_attention`` (no dropout) as elementwise products and sums: ``[..., L, heads, d]``."""
    q = query / jnp.sqrt(query.shape[-1]).astype(query.dtype)
    w = jnp.moveaxis(jnp.sum(q[..., :, None, :, :] * key[..., None, :, :, :], axis=-1), -1, -3)  # [..., h, Q, K]
    if mask is not None:
        w = jnp.where(mask, w, jnp.finfo(w.dtype).min)
    w = jax.nn.softmax(w, axis=-1)
    return jnp.sum(jnp.moveaxis(w, -3, -1)[..., None] * value[..., None, :, :, :], axis=-3)


def no_mixing(query, key, value, bias=None, mask=None, **_):
    return value


@contextlib.contextmanager
def attention_core(fn):
    """The entity network's attention with ``fn`` as its core (flax's own when None), for this block alone."""
    old = A.nn.MultiHeadDotProductAttention
    A.nn.MultiHeadDotProductAttention = functools.partial(old, attention_fn=fn) if fn else old
    try:
        yield
    finally:
        A.nn.MultiHeadDotProductAttention = old


def sgd_step(net_apply, batch, tx):
    zeros = jnp.zeros(N)

    def sgd(c, k):
        p, o = c
        g, aux = jax.grad(A.loss, has_aux=True)(p, net_apply, batch, jax.random.normal(k, (N,)), zeros, 0.2, 0.5,
                                                0.01)
        s, o = tx.update(g, o, p)
        return (jax.tree.map(lambda a, b: a - 1e-4 * b, p, s), o), aux[0]
    return sgd


def attention_cores(task: str) -> None:
    sim, sp = KeepAwayConfig.from_task(task), KeepAwayParams()
    obs, _ = gym.KeepAway(sim, "entities").reset_batch(jax.random.key(0), N, sp)
    net = A.EntityActorCritic(hidden=32, heads=4)
    params = net.init(jax.random.key(0), jax.tree.map(lambda a: a[0], obs))
    zeros, a0 = jnp.zeros(N), jnp.zeros((N,), jnp.int32)
    batch = A.Transition(obs, a0, zeros, zeros, zeros, jnp.zeros(N, bool), jnp.ones(N, jnp.int32), jnp.ones(N, bool))
    tx = A.optimiser(A.PPOConfig())
    with attention_core(None):
        ref = net.apply(params, obs)
    with attention_core(elementwise_attention):
        got = net.apply(params, obs)
    print(f"{task} elementwise core against flax's: logits differ by at most "
          f"{float(jnp.max(jnp.abs(ref[0] - got[0]))):.1e}, values by {float(jnp.max(jnp.abs(ref[1] - got[1]))):.1e}")
    for name, fn in (("flax's core", None), ("elementwise core", elementwise_attention), ("no mixing", no_mixing)):
        with attention_core(fn):
            def fwd(c, k):
                logits, value = net.apply(params, c)
                return jax.tree.map(lambda a: a + 1e-3 * value.reshape((-1,) + (1,) * (a.ndim - 1)), c), logits

            timeit(f"entities, {name}: forward", fwd, obs)
            timeit(f"entities, {name}: minibatch step (loss, gradient, Adam)", sgd_step(net.apply, batch, tx),
                   (params, tx.init(params)))


def main(task: str) -> None:
    sim, sp = KeepAwayConfig.from_task(task), KeepAwayParams()
    for kind, net in (("fixed", A.ActorCritic(hidden=32)), ("entities", A.EntityActorCritic(hidden=32, heads=4))):
        env = gym.KeepAway(sim, kind)
        obs, st = env.reset_batch(jax.random.key(0), N, sp)
        params = net.init(jax.random.key(0), jax.tree.map(lambda a: a[0], obs))
        print(f"{task} {kind}: {sum(x.size for x in jax.tree.leaves(params))} parameters")

        def fwd(c, k, net=net, params=params):
            logits, value = net.apply(params, c)
            return jax.tree.map(lambda a: a + 1e-3 * value.reshape((-1,) + (1,) * (a.ndim - 1)), c), logits

        timeit(f"{kind} forward", fwd, obs)
        a0 = jnp.zeros((N,), jnp.int32)
        timeit(f"{kind} iterate_batch with its observation",
               lambda s, k, env=env: (env.iterate_batch(k, s, a0, sp, 32)[1], None), st)
        timeit(f"{kind} observation alone", lambda s, k, env=env: (s, env.observation_batch(s)), st)
        tx = A.optimiser(A.PPOConfig())
        zeros = jnp.zeros(N)
        batch = A.Transition(obs, a0, zeros, zeros, zeros, jnp.zeros(N, bool), jnp.ones(N, jnp.int32),
                             jnp.ones(N, bool))
        timeit(f"{kind} minibatch step (loss, gradient, Adam)", sgd_step(net.apply, batch, tx),
               (params, tx.init(params)))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("task", nargs="?", default="4v3", help="the task, '<keepers>v<takers>' (default 4v3)")
    parser.add_argument("--attention", action="store_true",
                        help="time the entity network's attention cores instead (see above)")
    args = parser.parse_args()
    (attention_cores if args.attention else main)(args.task)
