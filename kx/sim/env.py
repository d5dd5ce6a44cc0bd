"""The keep-away world of SPEC §1 as pure functions: ``reset`` and ``step``.

Over 450 lines because the world's rules are one set of pure functions (reset, the takers, the kick, possession, the
step), which the plain reference implementation (kx.sim.reference) mirrors function for function.

Grid keep-away after Didi & Nitschke (2016), Table 2: a ``W x W`` field of integer cells, agents make
one king move per iteration, a passed ball travels two unit sub-steps per iteration, 4500 iterations
per trial. One iteration runs, in order: the holder's decision, the kick, the keepers' moves, the
takers' moves, the ball's flight, the tackle. ``docs/simulator.md`` states every rule with its numbers;
:mod:`kx.sim.reference` restates them one episode at a time in plain Python, and the tests hold this
module to it exactly.

All state arrays are batch-last (``[n, *B]`` per agent, ``[*B]`` per episode) and every function here
is rank-polymorphic in ``B``: a single episode is ``B == ()``.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from kx.sim import geometry as geo
from kx.sim.ops import any0, argmin0, col, fenced, pick, top_k_first  # noqa: F401 (also kx.sim.env's names)
from kx.sim.types import (
    DIST_SCALE,
    MAX_NOISE_FIELD,
    NOISE_DENOM,
    EpisodeStats,
    KeepAwayConfig,
    KeepAwayError,
    KeepAwayParams,
    Reason,
    State,
)

# Get-open scoring (integers; see docs/simulator.md, "Keepers get open").
OPEN_TAKER_W, OPEN_TAKER_CAP = 4, 5  # distance from the nearest taker, capped
OPEN_MATE_W, OPEN_MATE_CAP = 2, 4  # distance from the nearest teammate (anti-crowding), capped
OPEN_LANE_W = 6  # no taker within sqrt(2) cells of the straight lane from the ball
OPEN_FAR, OPEN_NEAR, OPEN_RANGE_W = 8, 3, 3  # stay within [NEAR, FAR] king moves of the ball
OPEN_EDGE_W = 4  # avoid the outermost ring of cells
MARK_DISTANCE = 2  # a marker stands this many king moves from its keeper, toward the ball (calibrated)
LANE_CONE = 2  # a taker blocks a lane within atan(1/2) = 26.6 degrees of it (calibrated)
# Interception sort keys: a feasible plan's key is its sub-step (< 128 on fields up to MAX_FIELD), an
# infeasible one's _INFEASIBLE // 2 + how late; both below _INFEASIBLE, packed above a cell's 18 bits.
_INFEASIBLE = 1 << 10
_PLAN_KEY_SHIFT = 18


def check(config: KeepAwayConfig, params: KeepAwayParams) -> None:
    """Validates a config and concrete params together; raises :class:`KeepAwayError` naming the field."""
    params.validate()
    kn = float(jnp.asarray(params.kick_noise_deg))
    if kn > 0 and config.field_size > MAX_NOISE_FIELD:
        raise KeepAwayError(
            f"kick_noise_deg: kick noise needs field_size <= {MAX_NOISE_FIELD} (exact integer pass geometry), "
            f"got field_size={config.field_size}"
        )
    pairs = config.n_keepers * (config.n_keepers - 1) // 2
    worst = pairs * DIST_SCALE * math.sqrt(2) * (config.field_size - 1) * int(jnp.asarray(params.max_iterations))
    if worst >= 2**31:
        raise KeepAwayError(
            f"max_iterations: {int(jnp.asarray(params.max_iterations))} is too many for {config.name} on a "
            f"{config.field_size}-cell field (the dispersion accumulator would overflow); use at most "
            f"{int((2**31 - 1) / (pairs * DIST_SCALE * math.sqrt(2) * (config.field_size - 1)))}"
        )


def noise_limit(kick_noise_deg) -> jax.Array:
    """Largest |s| of a kick-noise rotation atan(s/16) within ``kick_noise_deg``."""
    return jnp.floor(NOISE_DENOM * jnp.tan(jnp.deg2rad(kick_noise_deg)) + 1e-6).astype(jnp.int32)


def noise_words(key: jax.Array, trial_ids: jax.Array) -> jax.Array:
    """One uint32 word per episode, ``bits(fold_in(key, trial_id))``: the seed of that trial's kick
    noise (:func:`kick_noise`). Drawn once per evaluation, not once per iteration."""
    return jax.vmap(lambda i: jax.random.bits(jax.random.fold_in(key, i), (), jnp.uint32))(trial_ids)


def _mix32(x: jax.Array) -> jax.Array:
    """A 32-bit integer finaliser (Wellons' "lowbias32": two multiply-xorshift rounds, every output bit
    depends on every input bit)."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def kick_noise(word: jax.Array, t: jax.Array, s_max: jax.Array) -> jax.Array:
    """The kick-noise integer ``s`` in ``[-s_max, s_max]`` of iteration ``t`` of the trial seeded by
    ``word`` (all ``[*B]``): a counter-based hash of ``(word, t)``, so it is the same whatever lanes are
    batched together and costs a few integer operations per lane and iteration (threefry per lane and
    iteration cost more than the rest of the step). ``s`` takes the top 16 bits of the hash times
    ``2 s_max + 1``: uniform to within 2^-16 of each value's probability."""
    h = _mix32(word ^ _mix32(t.astype(jnp.uint32) * jnp.uint32(0x9E3779B9) + jnp.uint32(0x632BE5AB)))
    n = (2 * s_max + 1).astype(jnp.uint32)
    return ((h >> 16) * n >> 16).astype(jnp.int32) - s_max


# --------------------------------------------------------------------------------------------- reset


def reset(key: jax.Array, params: KeepAwayParams, config: KeepAwayConfig) -> State:
    """A start state: distinct random cells, the ball with a random keeper, no taker within
    ``start_clearance`` king moves of it. One episode; vmap (``out_axes=-1``) for a batch."""
    w, k, t = config.field_size, config.n_keepers, config.n_takers
    k_hold, k_keep, k_take = jax.random.split(key, 3)
    cells = jnp.arange(w * w, dtype=jnp.int32)
    cx, cy = cells % w, cells // w
    # Uniform distinct cells: the top-k of i.i.d. uniform scores (equal scores in cell order, on every backend)
    keeper_cells = top_k_first(jax.random.uniform(k_keep, (w * w,)), k)
    kx, ky = keeper_cells % w, keeper_cells // w
    holder = jax.random.randint(k_hold, (), 0, k, dtype=jnp.int32)
    hx, hy = kx[holder], ky[holder]
    taken = jnp.zeros(w * w, bool).at[keeper_cells].set(True)
    forbidden = taken | (geo.cheb(cx, cy, hx, hy) <= params.start_clearance)
    scores = jnp.where(forbidden, -1.0, jax.random.uniform(k_take, (w * w,)))
    taker_cells = top_k_first(scores, t)
    zero = jnp.zeros((), jnp.int32)
    return State(
        keeper_x=kx, keeper_y=ky, taker_x=taker_cells % w, taker_y=taker_cells // w,
        holder=holder, ball_x=hx, ball_y=hy, origin_x=hx, origin_y=hy,
        dir_x=jnp.ones((), jnp.int32), dir_y=zero, substep=zero,
        kicker=-jnp.ones((), jnp.int32), t=zero,
        done=jnp.zeros((), bool), reason=zero, passes=zero, contest=zero, dispersion_sum=zero,
        ball_centre_sum=zero, decisions=zero,
    )


def reset_batch(key: jax.Array, n: int, params: KeepAwayParams, config: KeepAwayConfig) -> State:
    """``n`` independent start states, batch-last (``[.., n]``). One compiled program per ``(n, config)``
    (eagerly, its operations were some sixty programs of their own per batch size, in every process); what
    it computes (integer and key arithmetic, uniform draws from bits, top-k) is exact, compiled or not."""
    return _reset_batch(key, params, n=int(n), config=config)


@functools.partial(jax.jit, static_argnames=("n", "config"))
def _reset_batch(key, params, *, n, config):
    return jax.vmap(lambda kk: reset(kk, params, config), out_axes=-1)(jax.random.split(key, n))


# ---------------------------------------------------------------------------------------------- step


def step(key: jax.Array, state: State, action: jax.Array, params: KeepAwayParams,
         config: KeepAwayConfig) -> State:
    """One iteration. ``action [*B]`` is the keeper the holder sends the ball to: its own index holds
    (so does any value outside ``[0, K)``); it is ignored while the ball is in flight. ``key`` draws the
    kick noise (unused when ``kick_noise_deg == 0``). Finished episodes are returned unchanged."""
    s_max = noise_limit(params.kick_noise_deg)
    noise = jax.random.randint(key, state.holder.shape, -s_max, s_max + 1, dtype=jnp.int32)
    return transition(state, action, noise, params, config)


def transition(state: State, action: jax.Array, noise: jax.Array, params: KeepAwayParams,
               config: KeepAwayConfig) -> State:
    """:func:`step` with the kick noise given: a pass is rotated by ``atan(noise / 16)``."""
    nk = config.n_keepers
    bnd = state.holder.ndim
    kid = col(nk, bnd)
    alive = ~state.done
    kx, ky, tx, ty = state.keeper_x, state.keeper_y, state.taker_x, state.taker_y

    # 1-2. Decision and kick.
    holding = state.holder >= 0
    act = jnp.where((action >= 0) & (action < nk), action, state.holder).astype(jnp.int32)
    kicks = alive & holding & (act != state.holder)
    rx, ry = pick(kx, act), pick(ky, act)
    dx, dy = rx - state.ball_x, ry - state.ball_y
    handoff = kicks & (dx == 0) & (dy == 0)  # receiver on the holder's own cell: completes at once
    launch = kicks & ~handoff
    noisy = noise != 0
    ex = jnp.where(noisy, NOISE_DENOM * dx - noise * dy, dx)
    ey = jnp.where(noisy, noise * dx + NOISE_DENOM * dy, dy)
    holder = jnp.where(launch, -1, jnp.where(handoff, act, state.holder))
    passes = state.passes + handoff.astype(jnp.int32)
    origin_x = jnp.where(launch, state.ball_x, state.origin_x)
    origin_y = jnp.where(launch, state.ball_y, state.origin_y)
    dir_x = jnp.where(launch, ex, state.dir_x)
    dir_y = jnp.where(launch, ey, state.dir_y)
    substep = jnp.where(launch, 0, state.substep)
    kicker = jnp.where(launch, state.holder, state.kicker)
    bx, by = state.ball_x, state.ball_y  # the ball has not moved yet this iteration
    flying = alive & (holder < 0)

    # 3a. Interception plan: each keeper aims at the pass cell nearest to it, ahead of the ball.
    # One plan for keepers and takers alike (rows 0..K-1 keepers, then takers), from their cells at
    # the start of the iteration.
    plan = fenced(functools.partial(_plan_interception, config=config), jnp.concatenate([kx, tx]),
                  jnp.concatenate([ky, ty]), origin_x, origin_y, dir_x, dir_y, substep)
    plan_code, plan_key = plan & ((1 << _PLAN_KEY_SHIFT) - 1), plan >> _PLAN_KEY_SHIFT
    ik_code, ik_key = plan_code[:nk], plan_key[:nk]
    ik_key = jnp.where(kid == kicker, 2 * _INFEASIBLE, ik_key)
    interceptor = argmin0(ik_key)
    tgt_x, tgt_y = geo.unpack(pick(ik_code, interceptor))
    # Where the ball is, or will be received: the reference point for getting open and marking.
    ref_x = jnp.where(flying, tgt_x, bx)
    ref_y = jnp.where(flying, tgt_y, by)

    # 3b. Keepers move: the holder stays, the interceptor runs to its cell, the rest get open.
    nkx, nky = geo.unpack(fenced(functools.partial(_keepers_move, config=config), kx, ky, tx, ty, ref_x,
                                 ref_y, flying, interceptor, holder, tgt_x, tgt_y, alive))

    # 4. Takers move, seeing the keepers' new cells: the nearest chase, the rest mark lanes. They react
    # to a pass taker_reaction_delay (0 or 1) iterations after its kick (calibrated, see
    # docs/calibration.md); until then they play as if the kicker still held the ball, on its cell.
    hold_x, hold_y = pick(nkx, jnp.maximum(holder, 0)), pick(nky, jnp.maximum(holder, 0))
    seen = flying & ~(launch & (params.taker_reaction_delay > 0))
    ball_ref_x = jnp.where(flying, bx, hold_x)  # bx: the ball's cell before this iteration's flight
    ball_ref_y = jnp.where(flying, by, hold_y)
    ntx, nty = geo.unpack(fenced(functools.partial(_takers_move, config=config), tx, ty, nkx, nky,
                                 jnp.where(flying, kicker, holder), seen, ball_ref_x, ball_ref_y,
                                 interceptor, tgt_x, tgt_y, plan_code[nk:], plan_key[nk:]))
    ntx, nty = jnp.where(alive, ntx, tx), jnp.where(alive, nty, ty)

    # 5. Ball flight in unit sub-steps: one fenced computation whose results come packed in one int32
    # (each output of a large fusion would recompute the whole flight).
    flight = fenced(functools.partial(_flight, config=config), flying, holder, state.reason, bx, by,
                    hold_x, hold_y, origin_x, origin_y, dir_x, dir_y, substep, kicker, nkx, nky, ntx, nty)
    ball_x, ball_y, reason, caught, holder, advanced = _unpack_flight(flight)
    substep = substep + advanced
    passes = passes + caught

    # 6. Tackle, in the RoboCup manner: a taker on the holder's cell contests the ball; the ball is lost
    # after tackle_iterations consecutive contested iterations. An uncontested holder resets the count;
    # while the ball flies it is kept (nobody is within reach of it).
    held_now = alive & (holder >= 0) & (reason == Reason.RUNNING)
    hx, hy = pick(nkx, jnp.maximum(holder, 0)), pick(nky, jnp.maximum(holder, 0))
    contested = held_now & any0((ntx == hx) & (nty == hy))
    contest = jnp.where(held_now, jnp.where(contested, state.contest + 1, 0), state.contest)
    tackled = contested & (contest >= params.tackle_iterations)
    reason = jnp.where(tackled, Reason.TACKLED, reason)

    # Bookkeeping: the iteration counts, statistics accumulate on the end-of-iteration positions.
    t = state.t + alive.astype(jnp.int32)
    reason = jnp.where(alive & (reason == Reason.RUNNING) & (t >= params.max_iterations),
                       Reason.TIME_LIMIT, reason)
    disp = _dispersion_q(nkx, nky, config)
    centre = _ball_centre_q(ball_x, ball_y, config)
    return State(
        keeper_x=nkx, keeper_y=nky, taker_x=ntx, taker_y=nty,
        holder=jnp.where(alive, holder, state.holder),
        ball_x=jnp.where(alive, ball_x, state.ball_x), ball_y=jnp.where(alive, ball_y, state.ball_y),
        origin_x=origin_x, origin_y=origin_y, dir_x=dir_x, dir_y=dir_y,
        substep=jnp.where(alive, substep, state.substep), kicker=kicker,
        t=t, done=state.done | (reason != Reason.RUNNING), reason=reason,
        passes=jnp.where(alive, passes, state.passes), contest=contest,
        dispersion_sum=state.dispersion_sum + jnp.where(alive, disp, 0),
        ball_centre_sum=state.ball_centre_sum + jnp.where(alive, centre, 0),
        decisions=state.decisions + (alive & holding).astype(jnp.int32),
    )


_FLIGHT_REASON, _FLIGHT_CAUGHT, _FLIGHT_HOLDER, _FLIGHT_ADVANCED = 18, 21, 22, 26


def _flight(in_air, holder, reason, bx, by, hold_x, hold_y, origin_x, origin_y, dir_x, dir_y, substep,
            kicker, nkx, nky, ntx, nty, config: KeepAwayConfig):
    """The ball's ``ball_speed`` unit sub-steps this iteration, packed into one int32 per episode:
    the ball's cell (18 bits, :func:`geo.pack`), the reason (3 bits), whether a keeper caught it (1),
    the holder + 1 (4) and the sub-steps advanced (4)."""
    w = config.field_size
    kid = col(config.n_keepers, holder.ndim)
    ball_x, ball_y = jnp.where(holder >= 0, hold_x, bx), jnp.where(holder >= 0, hold_y, by)
    caught = jnp.zeros_like(holder)
    advanced = jnp.zeros_like(holder)
    l2 = dir_x * dir_x + dir_y * dir_y
    inv = geo.inv_sqrt(l2)
    for _ in range(config.ball_speed):
        k = substep + advanced + 1
        cx, cy = geo.pass_cell(origin_x, origin_y, dir_x, dir_y, k, l2, inv)
        out = in_air & ~geo.inside(cx, cy, w)
        cut = in_air & ~out & any0((ntx == cx) & (nty == cy))
        on_k = (nkx == cx) & (nky == cy) & (kid != kicker)
        catch = in_air & ~out & ~cut & any0(on_k)
        catcher = argmin0(~on_k)
        advanced = advanced + in_air.astype(jnp.int32)
        ball_x, ball_y = jnp.where(in_air, cx, ball_x), jnp.where(in_air, cy, ball_y)
        reason = jnp.where(out, Reason.OUT_OF_FIELD, jnp.where(cut, Reason.INTERCEPTED, reason))
        holder = jnp.where(catch, catcher, holder)
        caught = caught | catch.astype(jnp.int32)
        in_air = in_air & ~out & ~cut & ~catch
    return (geo.pack(ball_x, ball_y) | (reason << _FLIGHT_REASON) | (caught << _FLIGHT_CAUGHT)
            | ((holder + 1) << _FLIGHT_HOLDER) | (advanced << _FLIGHT_ADVANCED))


def _unpack_flight(code):
    ball_x, ball_y = geo.unpack(code & ((1 << _FLIGHT_REASON) - 1))
    return (ball_x, ball_y, (code >> _FLIGHT_REASON) & 7, (code >> _FLIGHT_CAUGHT) & 1,
            ((code >> _FLIGHT_HOLDER) & 15) - 1, (code >> _FLIGHT_ADVANCED) & 15)


def _keepers_move(kx, ky, tx, ty, ref_x, ref_y, flying, interceptor, holder, tgt_x, tgt_y, alive,
                  config: KeepAwayConfig):
    """The keepers' new cells, packed (:func:`geo.pack`): the holder stays, the interceptor runs to
    its cell, the rest get open; finished episodes stay put."""
    spd = config.agent_speed
    kid = col(config.n_keepers, holder.ndim)
    ox, oy = kx, ky
    for _ in range(spd):
        ox, oy = _get_open(ox, oy, kx, ky, tx, ty, ref_x, ref_y, jnp.where(flying, interceptor, holder),
                           config)
    ix, iy = geo.toward(kx, ky, tgt_x, tgt_y, spd, config.field_size)
    is_int = flying & (kid == interceptor)
    is_holder = kid == holder
    nkx = jnp.where(is_holder, kx, jnp.where(is_int, ix, ox))
    nky = jnp.where(is_holder, ky, jnp.where(is_int, iy, oy))
    return geo.pack(jnp.where(alive, nkx, kx), jnp.where(alive, nky, ky))


def max_substep(config: KeepAwayConfig) -> int:
    """A bound on a pass's sub-steps inside the field: its cell is outside after this many."""
    return int(math.ceil((config.field_size - 1) * math.sqrt(2.0))) + 1


def _plan_interception(px, py, origin_x, origin_y, dir_x, dir_y, substep, config: KeepAwayConfig):
    """For agents at ``(px, py) [n, *B]``: the pass cell each aims at and a sort key.

    An agent aims at the cell of the pass sub-step nearest to it (its perpendicular foot on the ball's
    line, rounded), but at least one sub-step ahead of the ball. It can intercept there if the cell is
    inside the field and it can reach it, ``agent_speed`` king moves an iteration, by the iteration in
    which the ball gets there. The key sorts feasible agents by that sub-step (earliest first), then the
    infeasible ones by how late they would be.
    """
    k0 = substep
    kmax = max_substep(config)
    l2 = dir_x * dir_x + dir_y * dir_y
    inv = geo.inv_sqrt(l2)
    kp = geo.projection_substep(px, py, origin_x, origin_y, dir_x, dir_y, l2, inv)
    kt = jnp.clip(kp, k0 + 1, jnp.maximum(k0 + 1, kmax))
    cx, cy = geo.pass_cell(origin_x, origin_y, dir_x, dir_y, kt, l2, inv)
    reach = geo.cheb(px, py, cx, cy)
    moves = ((kt - k0 + config.ball_speed - 1) // config.ball_speed) * config.agent_speed
    ok = geo.inside(cx, cy, config.field_size) & (reach <= moves)
    key = jnp.where(ok, kt, _INFEASIBLE // 2 + jnp.maximum(reach - moves, 0))
    # one int32 (a second output would recompute the plan): the cell in the low bits, the key above
    return geo.pack(cx, cy) | (key << _PLAN_KEY_SHIFT)


def _get_open(kx, ky, snap_kx, snap_ky, tx, ty, ref_x, ref_y, skip, config: KeepAwayConfig):
    """Every keeper's get-open move, computed only for the K-1 keepers other than ``skip [*B]`` (the
    holder, or the interceptor while a pass flies), whose move is decided elsewhere."""
    nk = config.n_keepers
    bnd = kx.ndim - 1
    rows = col(nk - 1, bnd)
    idx = rows + (rows >= skip).astype(jnp.int32)  # [K-1, *B] keeper index of each row
    rx = jnp.stack([pick(kx, idx[r]) for r in range(nk - 1)])
    ry = jnp.stack([pick(ky, idx[r]) for r in range(nk - 1)])
    best_m = fenced(functools.partial(_get_open_move, config=config), rx, ry, idx, snap_kx, snap_ky, tx, ty,
                    ref_x, ref_y)
    kid = col(nk, bnd)
    own = pick(best_m, jnp.clip(kid - (kid > skip).astype(jnp.int32), 0, nk - 2))  # [K, *B]
    own = jnp.where(kid == skip, 0, own)
    mx, my = jnp.zeros_like(kx), jnp.zeros_like(ky)
    for i, (dx, dy) in enumerate(geo.MOVES.tolist()):
        mx, my = jnp.where(own == i, dx, mx), jnp.where(own == i, dy, my)
    return kx + mx, ky + my


def _get_open_move(kx, ky, self_id, snap_kx, snap_ky, tx, ty, ref_x, ref_y, config: KeepAwayConfig):
    """Index into ``geo.MOVES`` of the best move of keepers at ``kx, ky [n, *B]`` (keeper indices
    ``self_id [n, *B]``), by the get-open score.

    Written incrementally over the 9 candidates: Chebyshev distances are separable (``|dx|`` for the
    three x-offsets and ``|dy|`` for the three y-offsets, then a max per candidate) and the lane
    test's dot and cross products are linear in the move; all elementwise, so XLA fuses it into one
    vectorised loop (an ``argmax`` over a short leading axis does not vectorise on CPU).
    """
    w, nk, nt = config.field_size, config.n_keepers, config.n_takers
    offs = (-1, 0, 1)

    def sep_abs(a, b):  # |a + o - b| for o in offs
        d = a - b
        return {o: jnp.abs(d + o) for o in offs}

    v0x, v0y = kx - ref_x, ky - ref_y
    takers = []
    for j in range(nt):
        wx, wy = tx[j] - ref_x, ty[j] - ref_y
        takers.append((sep_abs(kx, tx[j]), sep_abs(ky, ty[j]), wx, wy, v0x * wx + v0y * wy,
                       v0x * wy - v0y * wx))
    mates = [(sep_abs(kx, snap_kx[m]), sep_abs(ky, snap_ky[m]), self_id == m) for m in range(nk)]
    ball_x, ball_y = sep_abs(kx, ref_x), sep_abs(ky, ref_y)
    vv0 = v0x * v0x + v0y * v0y
    best_s = best_m = None
    for m_index, (mx, my) in enumerate(geo.MOVES.tolist()):
        d_taker = None
        open_lane = None
        vv = vv0 + 2 * (mx * v0x + my * v0y) + (mx * mx + my * my)
        for ax, ay, wx, wy, dot0, cross0 in takers:
            d = jnp.maximum(ax[mx], ay[my])
            d_taker = d if d_taker is None else jnp.minimum(d_taker, d)
            dot = dot0 + (mx * wx + my * wy)
            cross = cross0 + (mx * wy - my * wx)
            blocked = (dot > 0) & (dot < vv) & (LANE_CONE * jnp.abs(cross) <= dot)
            open_lane = ~blocked if open_lane is None else open_lane & ~blocked
        d_mate = jnp.full(kx.shape, OPEN_MATE_CAP, jnp.int32)
        for ax, ay, is_self in mates:
            d_mate = jnp.minimum(d_mate, jnp.where(is_self, OPEN_MATE_CAP, jnp.maximum(ax[mx], ay[my])))
        d_ball = jnp.maximum(ball_x[mx], ball_y[my])
        cx, cy = kx + mx, ky + my
        edge = (cx == 0) | (cy == 0) | (cx == w - 1) | (cy == w - 1)
        score = (OPEN_TAKER_W * jnp.minimum(d_taker, OPEN_TAKER_CAP) + OPEN_MATE_W * d_mate
                 + OPEN_LANE_W * open_lane
                 - OPEN_RANGE_W * (jnp.maximum(d_ball - OPEN_FAR, 0) + jnp.maximum(OPEN_NEAR - d_ball, 0))
                 - OPEN_EDGE_W * edge)
        if best_s is None:  # staying is always inside the field
            best_s, best_m = score, jnp.zeros(kx.shape, jnp.int32)
        else:
            better = geo.inside(cx, cy, w) & (score > best_s)  # strict: the earlier move wins ties
            best_s = jnp.where(better, score, best_s)
            best_m = jnp.where(better, m_index, best_m)
    return best_m


def _takers_move(tx, ty, kx, ky, holder, flying, ball_x, ball_y, interceptor, tgt_x, tgt_y, cut_code,
                 cut_key, config: KeepAwayConfig):
    """Chasers (the ``n_chasers`` takers nearest the ball) go for the ball; markers cover lanes.
    Returns the takers' new cells, packed (:func:`geo.pack`).

    ``cut_code, cut_key [T, *B]`` are the takers' interception plans for the pass in flight."""
    nk, nt, spd = config.n_keepers, config.n_takers, config.agent_speed
    bnd = tx.ndim - 1
    tid, kid = col(nt, bnd), col(nk, bnd)
    d_ball = geo.cheb(tx, ty, ball_x, ball_y)  # [T, *B]
    # rank by (distance, index): the chasers are ranks 0 .. n_chasers-1.
    rank = jnp.zeros_like(d_ball)
    for m in range(nt):
        rank = rank + ((d_ball[m] < d_ball) | ((d_ball[m] == d_ball) & (m < tid))).astype(jnp.int32)
    chaser = rank < config.n_chasers
    # A chaser heads for the holder, or for its cut point of a pass if it can make it there in time,
    # else for the cell where the ball will be received.
    cut_x, cut_y = geo.unpack(cut_code)
    can_cut = cut_key < _INFEASIBLE // 2
    chase_x = jnp.where(flying, jnp.where(can_cut, cut_x, tgt_x), ball_x)
    chase_y = jnp.where(flying, jnp.where(can_cut, cut_y, tgt_y), ball_y)
    # Markers: the m-th marker (by rank) takes the m-th most open keeper (openness: distance to the
    # nearest chaser), excluding the keeper at the ball, and stands in its lane MARK_DISTANCE king
    # moves from it toward the ball.
    if nt > config.n_chasers:
        ball_keeper = jnp.where(flying, interceptor, holder)
        big = 4 * config.field_size
        open_k = jnp.full(kx.shape, big, jnp.int32)
        for j in range(nt):
            d = geo.cheb(kx, ky, tx[j], ty[j])
            open_k = jnp.minimum(open_k, jnp.where(chaser[j], d, big))
        eligible = kid != ball_keeper
        open_k = jnp.where(eligible, open_k, -1)
        k_rank = jnp.zeros_like(open_k)
        for m in range(nk):
            k_rank = k_rank + ((open_k[m] > open_k) | ((open_k[m] == open_k) & (m < kid))).astype(jnp.int32)
        n_elig = nk - 1
        m_rank = (rank - config.n_chasers) % n_elig  # [T, *B]
        # keeper whose openness rank equals each marker's rank
        match = k_rank[None] == m_rank[:, None]  # [T, K, *B]
        mk_x = jnp.sum(jnp.where(match, kx[None], 0), axis=1)
        mk_y = jnp.sum(jnp.where(match, ky[None], 0), axis=1)
        mark_x = mk_x + jnp.clip(ball_x - mk_x, -MARK_DISTANCE, MARK_DISTANCE)
        mark_y = mk_y + jnp.clip(ball_y - mk_y, -MARK_DISTANCE, MARK_DISTANCE)
        goal_x = jnp.where(chaser, chase_x, mark_x)
        goal_y = jnp.where(chaser, chase_y, mark_y)
    else:
        goal_x, goal_y = chase_x, chase_y
    return geo.pack(*geo.toward(tx, ty, goal_x, goal_y, spd, config.field_size))


def _dispersion_q(kx, ky, config: KeepAwayConfig):
    """Sum over keeper pairs of ``DIST_SCALE * distance``, each rounded (exact integers)."""
    total = jnp.zeros(kx.shape[1:], jnp.int32)
    for i in range(config.n_keepers):
        for j in range(i + 1, config.n_keepers):
            dx, dy = kx[i] - kx[j], ky[i] - ky[j]
            total = total + geo.round_scaled_sqrt(dx * dx + dy * dy, DIST_SCALE)
    return total


def _ball_centre_q(bx, by, config: KeepAwayConfig):
    """``DIST_SCALE * distance`` from the ball's cell (clipped into the field) to the field centre."""
    w = config.field_size
    cx, cy = jnp.clip(bx, 0, w - 1), jnp.clip(by, 0, w - 1)
    ux, uy = 2 * cx - (w - 1), 2 * cy - (w - 1)  # doubled coordinates relative to the centre
    return geo.round_scaled_sqrt(ux * ux + uy * uy, DIST_SCALE // 2)


# -------------------------------------------------------------------------------------- statistics


def max_pair_distance_sum(n_keepers: int, field_size: int) -> float:
    """The largest sum of pairwise Euclidean distances ``n_keepers`` agents can have on the field.

    The sum of the distances is a convex function of the agents' positions, so over the square
    ``[0, W-1]^2`` (a product of convex polygons) its maximum lies at a vertex: every agent on a corner
    cell (cells may be shared). With ``p`` agents on one diagonal's two corners and ``q = K - p`` on the
    other's, split as evenly as possible, the sum is ``(W-1) (p q + sqrt2 (floor(p^2/4) + floor(q^2/4)))``
    (sides between the diagonals, diagonals within them); the maximum over ``p`` is exact for the grid
    too, since corners are cells. Per pair ((W-1) units): 1.138 for K = 3 and 4, 1.024 for 5, 1.005
    for 6, 0.975 for 7 and 8, against sqrt2 = 1.414 for the diagonal.
    """
    k, side = n_keepers, field_size - 1
    return side * max(p * (k - p) + math.sqrt(2.0) * (p * p // 4 + (k - p) ** 2 // 4) for p in range(k + 1))


def behaviour_bounds(config: KeepAwayConfig, params: KeepAwayParams | None = None):
    """The fixed normalisers of the three behaviour statistics, ``(passes, dispersion, ball_centre)``:
    static Python floats that depend only on the task's config (``params`` is accepted and unused).

    * **passes**, per iteration played: 1.0. At most one pass completes in an iteration (one ball;
      a catch ends its flight, a hand-off replaces the kick), and one can complete in every
      iteration: a hand-off to a teammate on the holder's cell, or a kick to one within
      ``ball_speed`` cells, completes in the iteration of its decision, and the receiver can kick in
      the next. The same rule bounds the count by ``max_iterations``, the normaliser of the first kx
      versions; under the calibrated defaults episodes last 0.2-9% of it, so that normaliser put
      every team in [0, 0.011] (3v2: random 0.0005, heuristic 0.0046) and the dimension never moved
      a distance. As a rate over the iterations played, like the other two means, it is bounded by the
      same rule and spans what play does (docs/simulator.md has the measured spread).
    * **dispersion**, the mean pairwise keeper distance: :func:`max_pair_distance_sum` / ``C(K, 2)``,
      the exact largest mean K keepers can have (all on corners, never exceeded by an iteration, so
      never by the episode's mean): 0.805 of the diagonal for K = 3, 4; 0.724 for 5; 0.710 for 6;
      0.690 for 7, 8.
    * **ball_centre**, the ball's cell's distance from the field centre: ``(W-1) sqrt2 / 2``, half the
      diagonal, attained on a corner cell (the statistic clips the ball's cell into the field).

    The fixed-point accumulators round each distance to 1/32 cell, which can put a corner a hair
    above its bound: the statistics are clipped to [0, 1].
    """
    del params
    pairs = config.n_keepers * (config.n_keepers - 1) // 2
    dispersion = max_pair_distance_sum(config.n_keepers, config.field_size) / pairs
    return 1.0, dispersion, (config.field_size - 1) * math.sqrt(2.0) / 2.0


def episode_stats(state: State, params: KeepAwayParams, config: KeepAwayConfig) -> EpisodeStats:
    """Fitness, termination and the normalised behaviour vector of (finished) episodes.

    Fitness is iterations survived / max_iterations: an iteration in which the ball was lost does not
    count. Behaviour (each a mean over the iterations executed, divided by its bound in
    :func:`behaviour_bounds` and clipped to [0, 1]): completed passes per iteration (bound 1); the mean
    pairwise keeper distance (bound: the largest mean K keepers can have on the field, all on
    corners); the ball's distance from the centre (bound: half the diagonal).
    """
    return stats_from_counts(state.t, state.reason, state.passes, state.dispersion_sum,
                             state.ball_centre_sum, state.decisions, params, config)


def stats_from_counts(t, reason, passes, dispersion_sum, ball_centre_sum, decisions, params: KeepAwayParams,
                      config: KeepAwayConfig) -> EpisodeStats:
    """:func:`episode_stats` from an episode's integer counters (all ``[*B]``)."""
    lost = (reason == Reason.INTERCEPTED) | (reason == Reason.TACKLED) | (reason == Reason.OUT_OF_FIELD)
    survived = t - lost.astype(jnp.int32)
    # XLA rewrites x / broadcast(m) as x * broadcast(1 / m), one ulp off the quotient, where m has no
    # other use; behind the barrier it cannot, so every program (and eager code) divides exactly.
    max_it = jax.lax.optimization_barrier(
        jnp.broadcast_to(jnp.asarray(params.max_iterations, jnp.float32), survived.shape))
    fitness = survived.astype(jnp.float32) / max_it
    steps = jnp.maximum(t, 1).astype(jnp.float32)
    n_pairs = config.n_keepers * (config.n_keepers - 1) // 2
    pass_bound, disp_bound, centre_bound = behaviour_bounds(config)
    rate = passes.astype(jnp.float32) / (steps * pass_bound)
    disp = dispersion_sum.astype(jnp.float32) / (steps * n_pairs * DIST_SCALE * disp_bound)
    centre = ball_centre_sum.astype(jnp.float32) / (steps * DIST_SCALE * centre_bound)
    behaviour = jnp.stack([jnp.minimum(rate, 1.0), jnp.minimum(disp, 1.0), jnp.minimum(centre, 1.0)])
    return EpisodeStats(fitness=fitness, iterations=t, reason=reason, passes=passes, behaviour=behaviour,
                        decisions=decisions)


def as_numpy(state: State) -> dict[str, np.ndarray]:
    """The state's fields as numpy arrays (for the reference, rendering and tests)."""
    return {f: np.asarray(getattr(state, f)) for f in state.__dataclass_fields__}
