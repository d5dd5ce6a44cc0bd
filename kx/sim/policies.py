"""Hand-coded baseline policies and a small fixed-topology neural policy.

A *policy* is ``apply(params, state, key) -> action``: ``state`` a :class:`~kx.sim.types.State`,
``key`` a PRNG key array (``[*B]`` keys; only stochastic policies read it), ``action`` a keeper index
per episode (the holder's own index holds). :class:`Policy` bundles ``apply`` with whether it needs
keys, so that the evaluator derives them only when they are used, and with how it takes its
parameters:

* per lane (``shared=False``, the default): ``params`` is a pytree whose leaves are batch-last like the
  state, one parameter set per episode lane (``None`` for parameter-free policies); the evaluator
  copies each policy's set into every lane that plays it.
* shared (``shared=True``): ``params`` is :class:`Shared` ``(table, index)``, the whole table of G
  parameter sets (leading axis G on every leaf, the same arrays for every lane) and each lane's row
  of it; ``apply`` gathers what it needs itself (``table["w"][index]``). For parameters too large to
  copy per lane: 150 HyperNEAT substrates of 400 x 400 float32 weights are 96 MB shared, 2.9 GB
  copied into 4500 lanes.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from kx.sim import geometry as geo
from kx.sim import observe
from kx.sim.ops import pick
from kx.sim.types import KeepAwayConfig, State

PolicyApply = Callable[[Any, State, jax.Array], jax.Array]


@dataclasses.dataclass(frozen=True)
class Policy:
    """A policy for the evaluator: ``apply(params, state, key) -> action``.

    ``stochastic``: ``apply`` reads ``key``. ``shared``: ``apply`` takes :class:`Shared` parameters
    (one table for all lanes and each lane's row) instead of a parameter set per lane.
    """

    name: str
    apply: PolicyApply
    stochastic: bool = False
    shared: bool = False


class Shared(NamedTuple):
    """The parameters a shared policy's ``apply`` receives.

    ``table``: the G parameter sets of a generation, a pytree with a leading axis G on every leaf, the
    same arrays for every lane (on every device, when lanes are split over several). It is passed to
    the compiled evaluator as an argument, so new values each generation do not recompile.
    ``index``: each lane's policy, the row of ``table`` it plays (int32, batch-last like the state).
    """

    table: Any  # leaves [G, ...]
    index: jax.Array  # [*B] int32


@functools.lru_cache(maxsize=None)
def always_hold(config: KeepAwayConfig) -> Policy:
    return Policy("hold", lambda params, state, key: jnp.maximum(state.holder, 0))


@functools.lru_cache(maxsize=None)
def random_policy(config: KeepAwayConfig) -> Policy:
    """Uniform over the K actions: hold or pass to any one teammate."""

    def apply(params, state, key):
        draw = jax.vmap(lambda k: jax.random.randint(k, (), 0, config.n_keepers, dtype=jnp.int32))
        flat = draw(key.reshape(-1))
        return flat.reshape(state.holder.shape)

    return Policy("random", apply, stochastic=True)


#: How far apart two of the heuristic's margins must be to count as different. The margins are float32
#: sums like ``|a - s u_x| - s / 2`` and are often exactly 0 or exactly equal between teammates; a platform
#: that rounds them otherwise (a fused multiply-add, as GPU compilers form by default) can put such a 0 a
#: hair below 0, where the policy held and lost the ball: on an H200 the heuristic's mean fitness on
#: kx.bench sim's 4500 states was 0.0150 against this CPU's 0.0235, and counting the zeros unsafe here
#: gives 0.0106 (docs/benchmarks.md, "On a GPU"; that this is what the H200 did is not yet checked).
#: Margins are sums of a few cells, so float32 rounds them by about 1e-6; 1e-4 is far above that and far
#: below any real difference of cells. On this CPU it changed the outcome of 0.6-2% of 54,000 episodes of
#: every task, where equal margins had been told apart by their last bit (each task's mean fitness within
#: 0.0004 of before; 2026-12-04, scripts/heuristic_tolerance.py at 412c231).
MARGIN_TOL = 1e-4


@functools.lru_cache(maxsize=None)
def heuristic(config: KeepAwayConfig, threshold: int = 2, min_margin: float = 0.0) -> Policy:
    """Hold until a taker is within ``threshold`` king moves, then pass to the most open teammate.

    Openness of a teammate is the margin by which the takers miss its pass: along the straight pass
    from the holder H in unit direction u, a taker at T is ``cheb(T, H + s u)`` king moves from the
    ball when the ball has travelled s cells, and has made about ``s / 2`` moves by then (ball speed 2,
    agent speed 1). The margin is ``min over takers and s in [0, |pass|] of cheb(T, H + s u) - s / 2``,
    computed exactly: the function is convex and piecewise linear in s, so its minimum lies at one of
    at most six breakpoints. The holder passes to the teammate with the largest margin if that margin
    is at least ``min_margin``, and holds otherwise; margins within :data:`MARGIN_TOL` of each other, or
    of ``min_margin``, count as equal (the first teammate of equal margins, in keeper order, gets the ball).
    """
    speed_ratio = config.agent_speed / config.ball_speed

    def apply(params, state, key):
        h = jnp.maximum(state.holder, 0)
        kx, ky, tx, ty = state.keeper_x, state.keeper_y, state.taker_x, state.taker_y
        hx, hy = pick(kx, h), pick(ky, h)
        d_near = geo.cheb(tx, ty, hx, hy)
        pressed = d_near[0] <= threshold
        for j in range(1, config.n_takers):
            pressed = pressed | (d_near[j] <= threshold)
        # Only the K-1 teammates (rows in keeper order, skipping the holder): a pass to oneself is
        # no pass. Each row is its own [*B] arrays rather than a row of a stacked [K-1, *B] array:
        # XLA CPU's fusion emitter computes a stacked intermediate read at several rows in a
        # function of the row that it does not inline, and so does not vectorise the loop (measured
        # 30 ns a lane for this policy stacked, 2026-12-02).
        takers = [((tx[j] - hx).astype(jnp.float32), (ty[j] - hy).astype(jnp.float32))
                  for j in range(config.n_takers)]
        best = target = None
        for r in range(config.n_keepers - 1):
            i = r + (r >= h).astype(jnp.int32)  # [*B] keeper index of the row
            dx, dy = (pick(kx, i) - hx).astype(jnp.float32), (pick(ky, i) - hy).astype(jnp.float32)
            length = jnp.sqrt(dx * dx + dy * dy)
            inv = 1.0 / jnp.maximum(length, 1e-6)
            ux, uy = dx * inv, dy * inv
            margin = jnp.full(dx.shape, jnp.inf, jnp.float32)

            def recip(den):  # 1/den where defined (the breakpoint exists)
                ok = jnp.abs(den) > 1e-6
                return ok, 1.0 / jnp.where(ok, den, 1.0)

            slopes = [recip(ux), recip(uy), recip(ux - uy), recip(ux + uy)]
            for a, b in takers:

                def f(s):
                    p, q = jnp.abs(a - s * ux), jnp.abs(b - s * uy)
                    return jnp.where(p > q, p, q) - speed_ratio * s

                def fmin(p, q):
                    return jnp.where(q < p, q, p)

                aa, ab = jnp.abs(a), jnp.abs(b)
                m = fmin(jnp.where(aa > ab, aa, ab), f(length))  # f(0) = cheb(T, H)
                for num, (ok, rec) in zip((a, b, a - b, a + b), slopes):
                    t = num * rec
                    t = jnp.where(t > 0.0, t, 0.0)
                    t = jnp.where(t < length, t, length)
                    m = fmin(m, f(jnp.where(ok, t, 0.0)))
                margin = fmin(margin, m)
            # the first teammate (in keeper order) with the largest margin
            if best is None:
                best, target = margin, i
            else:
                better = margin > best + MARGIN_TOL
                best, target = jnp.where(better, margin, best), jnp.where(better, i, target)
        safe = best >= min_margin - MARGIN_TOL
        return jnp.where(pressed & safe, target, h)

    return Policy("heuristic", apply)


# ------------------------------------------------------------------------------ small neural policy


def mlp_init(key: jax.Array, n: int, config: KeepAwayConfig, hidden: int = 8, layout: str = "fixed"):
    """``n`` random parameter sets of an ``inputs -> hidden (tanh) -> outputs`` network, leading axis n."""
    n_in, n_out = observe.n_inputs(layout, config), observe.n_outputs(layout, config)
    k1, k2 = jax.random.split(key)
    return {
        "w1": jax.random.normal(k1, (n, n_in, hidden)) / math.sqrt(n_in),
        "b1": jnp.zeros((n, hidden)),
        "w2": jax.random.normal(k2, (n, hidden, n_out)) / math.sqrt(hidden),
        "b2": jnp.zeros((n, n_out)),
    }


@functools.lru_cache(maxsize=None)
def mlp_policy(config: KeepAwayConfig, layout: str = "fixed") -> Policy:
    """A fixed-topology network on the ``fixed`` or ``full`` layout; params batch-last
    (``w1 [in, hidden, *B]`` ...)."""
    obs_fn = {"fixed": observe.fixed_obs, "full": observe.full_obs}[layout]

    def apply(params, state, key):
        x = obs_fn(state, config)  # [in, *B]
        hid = jnp.tanh(jnp.sum(x[:, None] * params["w1"], axis=0) + params["b1"])
        out = jnp.sum(hid[:, None] * params["w2"], axis=0) + params["b2"]
        return observe.decode_ranked(out, state, config)

    return Policy(f"mlp-{layout}", apply)


@functools.lru_cache(maxsize=None)
def linear_policy(config: KeepAwayConfig, layout: str = "fixed", shared: bool = False) -> Policy:
    """A linear policy on the ``fixed`` or ``full`` layout: outputs ``x W + b``, the largest acts (ties
    to hold). :func:`linear_params` builds the parameters from flat vectors.

    Per lane (``shared=False``) the evaluator gives ``apply`` batch-last params, ``w [in, out, *B]``
    and ``b [out, *B]``; shared (``shared=True``) it gives :class:`Shared` with the table ``{"w":
    [G, in, out], "b": [G, out]}`` as :func:`linear_params` returns it, and each lane gathers its row.
    Both compute the same sums in the same order, so their actions are equal.
    """
    obs_fn = {"fixed": observe.fixed_obs, "full": observe.full_obs}[layout]

    def act(w, b, state):  # w [in, out, *B], b [out, *B]
        x = obs_fn(state, config)  # [in, *B]
        out = b
        for i in range(x.shape[0]):  # unrolled: a short contraction stays elementwise and fuses
            out = out + x[i][None] * w[i]
        return observe.decode_ranked(out, state, config)

    if not shared:
        return Policy(f"linear-{layout}", lambda params, state, key: act(params["w"], params["b"], state))

    def apply_shared(params: Shared, state, key):
        nd = params.index.ndim
        w = jnp.moveaxis(params.table["w"][params.index], tuple(range(nd)), tuple(range(-nd, 0)))
        b = jnp.moveaxis(params.table["b"][params.index], tuple(range(nd)), tuple(range(-nd, 0)))
        return act(w, b, state)

    return Policy(f"linear-{layout}-shared", apply_shared, shared=True)


def linear_params(flat: jax.Array, config: KeepAwayConfig, layout: str = "fixed") -> dict:
    """``[n, in * out + out]`` flat parameter vectors (weights row-major by input, then biases) as
    :func:`linear_policy` parameters with a leading axis ``n``."""
    n_in, n_out = observe.n_inputs(layout, config), observe.n_outputs(layout, config)
    if flat.shape[-1] != n_in * n_out + n_out:
        raise ValueError(f"linear_params: {flat.shape[-1]} values per policy, the {layout!r} layout of "
                         f"{config.name} needs {n_in * n_out + n_out}")
    return {"w": flat[:, : n_in * n_out].reshape(-1, n_in, n_out), "b": flat[:, n_in * n_out:]}


BASELINES = {"hold": always_hold, "random": random_policy, "heuristic": heuristic}
