"""Plain-Python reference of the keep-away rules: one episode, no JAX, written to be read.

It restates docs/simulator.md independently of :mod:`kx.sim.env` (lists and tuples, ``math``), and the
tests hold the JAX step to it exactly. The only irrational quantity, the ball's position on a pass,
is rounded in float64 here and in exact integer arithmetic in JAX; the margin to a rounding boundary is
far above float64's error (see :mod:`kx.sim.geometry`), so both give the same cells.
"""

from __future__ import annotations

import dataclasses
import math

from kx.sim.types import DIST_SCALE, NOISE_DENOM, KeepAwayConfig, Reason

KING_MOVES = [(0, 0), (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1)]
INFEASIBLE = 1 << 20


@dataclasses.dataclass
class RefState:
    keepers: list[tuple[int, int]]
    takers: list[tuple[int, int]]
    holder: int  # -1 while the ball is in flight
    ball: tuple[int, int]
    origin: tuple[int, int]
    direction: tuple[int, int]
    substep: int
    kicker: int
    t: int = 0
    done: bool = False
    reason: int = Reason.RUNNING
    passes: int = 0
    contest: int = 0
    dispersion_sum: int = 0
    ball_centre_sum: int = 0
    decisions: int = 0

    @classmethod
    def from_arrays(cls, a: dict) -> "RefState":
        """From :func:`kx.sim.env.as_numpy` of one episode."""
        i = lambda v: int(v)  # noqa: E731
        return cls(
            keepers=[(i(x), i(y)) for x, y in zip(a["keeper_x"], a["keeper_y"])],
            takers=[(i(x), i(y)) for x, y in zip(a["taker_x"], a["taker_y"])],
            holder=i(a["holder"]), ball=(i(a["ball_x"]), i(a["ball_y"])),
            origin=(i(a["origin_x"]), i(a["origin_y"])), direction=(i(a["dir_x"]), i(a["dir_y"])),
            substep=i(a["substep"]), kicker=i(a["kicker"]), t=i(a["t"]),
            done=bool(a["done"]), reason=i(a["reason"]), passes=i(a["passes"]),
            contest=i(a["contest"]), dispersion_sum=i(a["dispersion_sum"]), ball_centre_sum=i(a["ball_centre_sum"]),
            decisions=i(a["decisions"]),
        )

    def as_dict(self) -> dict:
        return {
            "keeper_x": [p[0] for p in self.keepers], "keeper_y": [p[1] for p in self.keepers],
            "taker_x": [p[0] for p in self.takers], "taker_y": [p[1] for p in self.takers],
            "holder": self.holder, "ball_x": self.ball[0], "ball_y": self.ball[1],
            "origin_x": self.origin[0], "origin_y": self.origin[1],
            "dir_x": self.direction[0], "dir_y": self.direction[1], "substep": self.substep,
            "kicker": self.kicker, "t": self.t, "done": self.done,
            "reason": self.reason, "passes": self.passes, "contest": self.contest,
            "dispersion_sum": self.dispersion_sum,
            "ball_centre_sum": self.ball_centre_sum, "decisions": self.decisions,
        }


def cheb(a, b) -> int:
    return max(abs(a[0] - b[0]), abs(a[1] - b[1]))


def step_toward(p, goal, speed: int, w: int):
    """Up to ``speed`` king moves straight toward ``goal``, never leaving the field."""
    dx = max(-speed, min(speed, goal[0] - p[0]))
    dy = max(-speed, min(speed, goal[1] - p[1]))
    return (min(max(p[0] + dx, 0), w - 1), min(max(p[1] + dy, 0), w - 1))


def inside(p, w: int) -> bool:
    return 0 <= p[0] < w and 0 <= p[1] < w


def rounded(v: float) -> int:
    """Nearest integer; halves cannot occur for the quantities rounded here."""
    return math.floor(v + 0.5) if v >= 0 else -math.floor(-v + 0.5)


def ball_cell(origin, direction, k: int):
    """The cell of the ball after k unit sub-steps along the pass."""
    length = math.sqrt(direction[0] ** 2 + direction[1] ** 2)
    return (origin[0] + rounded(k * direction[0] / length), origin[1] + rounded(k * direction[1] / length))


def max_substep(w: int) -> int:
    return int(math.ceil((w - 1) * math.sqrt(2.0))) + 1


def interception_plan(agent, s: RefState, cfg: KeepAwayConfig):
    """(aim cell, sort key) of one agent for the pass in flight; see docs/simulator.md."""
    length = math.sqrt(s.direction[0] ** 2 + s.direction[1] ** 2)
    dot = (agent[0] - s.origin[0]) * s.direction[0] + (agent[1] - s.origin[1]) * s.direction[1]
    k_foot = rounded(max(dot, 0) / length)
    k = min(max(k_foot, s.substep + 1), max(s.substep + 1, max_substep(cfg.field_size)))
    cell = ball_cell(s.origin, s.direction, k)
    iterations = -(-(k - s.substep) // cfg.ball_speed)
    moves = iterations * cfg.agent_speed
    reach = cheb(agent, cell)
    if inside(cell, cfg.field_size) and reach <= moves:
        return cell, k
    return cell, INFEASIBLE // 2 + max(reach - moves, 0)


def get_open_move(i: int, pos, s: RefState, ref, cfg: KeepAwayConfig):
    """Best cell for keeper i among staying and its 8 neighbours (first best in KING_MOVES order)."""
    w = cfg.field_size
    best, best_score = pos, None
    for mx, my in KING_MOVES:
        c = (pos[0] + mx, pos[1] + my)
        if not inside(c, w):
            continue
        d_taker = min([5] + [cheb(c, t) for t in s.takers])
        d_mate = min([4] + [cheb(c, k) for m, k in enumerate(s.keepers) if m != i])
        v = (c[0] - ref[0], c[1] - ref[1])
        vv = v[0] ** 2 + v[1] ** 2
        lane_open = True
        for t in s.takers:
            u = (t[0] - ref[0], t[1] - ref[1])
            dot = v[0] * u[0] + v[1] * u[1]
            cross = v[0] * u[1] - v[1] * u[0]
            if 0 < dot < vv and 2 * abs(cross) <= dot:  # within atan(1/2) of the lane, ahead
                lane_open = False
        d_ball = cheb(c, ref)
        edge = c[0] in (0, w - 1) or c[1] in (0, w - 1)
        score = (4 * d_taker + 2 * d_mate + 6 * lane_open - 3 * max(d_ball - 8, 0)
                 - 3 * max(3 - d_ball, 0) - 4 * edge)
        if best_score is None or score > best_score:
            best, best_score = c, score
    return best


def step(s: RefState, action: int, noise: int, cfg: KeepAwayConfig, max_iterations: int,
         taker_reaction_delay: int = 1, tackle_iterations: int = 3) -> RefState:
    """One iteration of the rules; returns a new state (a finished episode is returned as is)."""
    if s.done:
        return s
    s = dataclasses.replace(s, keepers=list(s.keepers), takers=list(s.takers))
    w, nk = cfg.field_size, cfg.n_keepers

    # 1-2. Decision and kick.
    if s.holder >= 0:
        s.decisions += 1
        target = action if 0 <= action < nk else s.holder
        if target != s.holder:
            d = (s.keepers[target][0] - s.ball[0], s.keepers[target][1] - s.ball[1])
            if d == (0, 0):  # hand-off to a teammate on the same cell
                s.holder = target
                s.passes += 1
            else:
                if noise:
                    d = (NOISE_DENOM * d[0] - noise * d[1], noise * d[0] + NOISE_DENOM * d[1])
                s.kicker = s.holder
                s.holder = -1
                s.origin, s.direction, s.substep = s.ball, d, 0
    flying = s.holder < 0
    just_kicked = flying and s.substep == 0

    # 3. Keepers move (all from the same snapshot).
    interceptor, aim = -1, None
    if flying:
        best_key = None
        for i, k in enumerate(s.keepers):
            if i == s.kicker:
                continue
            cell, key = interception_plan(k, s, cfg)
            if best_key is None or key < best_key:
                interceptor, aim, best_key = i, cell, key
    ref = aim if flying else s.ball
    moved = []
    for i, k in enumerate(s.keepers):
        if i == s.holder:
            moved.append(k)
        elif i == interceptor:
            moved.append(step_toward(k, aim, cfg.agent_speed, w))
        else:
            p = k
            for _ in range(cfg.agent_speed):
                p = get_open_move(i, p, s, ref, cfg)
            moved.append(p)
    s.keepers = moved

    # 4. Takers move, seeing the keepers' new cells. With a reaction delay they treat a pass kicked in
    # this iteration as if the kicker still held the ball.
    takers_see_pass = flying and not (just_kicked and taker_reaction_delay)
    if takers_see_pass:
        ball_now = s.ball
    elif flying:
        ball_now = s.ball  # the kicker's cell, where the ball still is
    else:
        ball_now = s.keepers[s.holder]
    order = sorted(range(cfg.n_takers), key=lambda j: (cheb(s.takers[j], ball_now), j))
    chasers, markers = order[: cfg.n_chasers], order[cfg.n_chasers:]
    goals = {}
    for j in chasers:
        if takers_see_pass:
            cell, key = interception_plan(s.takers[j], s, cfg)
            goals[j] = cell if key < INFEASIBLE // 2 else aim
        else:
            goals[j] = ball_now
    if markers:
        ball_keeper = interceptor if takers_see_pass else (s.kicker if flying else s.holder)
        openness = {i: min(cheb(k, s.takers[j]) for j in chasers)
                    for i, k in enumerate(s.keepers) if i != ball_keeper}
        ranked = sorted(openness, key=lambda i: (-openness[i], i))
        for m, j in enumerate(markers):
            k = s.keepers[ranked[m % len(ranked)]]
            # in the keeper's passing lane, two king moves from it toward the ball
            goals[j] = (k[0] + max(-2, min(2, ball_now[0] - k[0])), k[1] + max(-2, min(2, ball_now[1] - k[1])))
    s.takers = [step_toward(t, goals[j], cfg.agent_speed, w) for j, t in enumerate(s.takers)]

    # 5. Ball flight.
    if flying:
        for _ in range(cfg.ball_speed):
            s.substep += 1
            cell = ball_cell(s.origin, s.direction, s.substep)
            s.ball = cell
            if not inside(cell, w):
                s.reason = Reason.OUT_OF_FIELD
                break
            if cell in s.takers:
                s.reason = Reason.INTERCEPTED
                break
            catchers = [i for i, k in enumerate(s.keepers) if k == cell and i != s.kicker]
            if catchers:
                s.holder = catchers[0]
                s.passes += 1
                break
    else:
        s.ball = s.keepers[s.holder]

    # 6. Tackle: a taker on the holder's cell contests the ball; tackle_iterations contested held
    # iterations in a row lose it. A held, uncontested iteration resets the count; a flight keeps it.
    if s.reason == Reason.RUNNING and s.holder >= 0:
        if s.keepers[s.holder] in s.takers:
            s.contest += 1
            if s.contest >= tackle_iterations:
                s.reason = Reason.TACKLED
        else:
            s.contest = 0

    s.t += 1
    if s.reason == Reason.RUNNING and s.t >= max_iterations:
        s.reason = Reason.TIME_LIMIT
    s.done = s.reason != Reason.RUNNING
    for a in range(nk):
        for b in range(a + 1, nk):
            d2 = (s.keepers[a][0] - s.keepers[b][0]) ** 2 + (s.keepers[a][1] - s.keepers[b][1]) ** 2
            s.dispersion_sum += math.floor(DIST_SCALE * math.sqrt(d2) + 0.5)
    bx, by = min(max(s.ball[0], 0), w - 1), min(max(s.ball[1], 0), w - 1)
    centre_d2 = (2 * bx - (w - 1)) ** 2 + (2 * by - (w - 1)) ** 2  # doubled coordinates
    s.ball_centre_sum += math.floor(DIST_SCALE * math.sqrt(centre_d2) / 2 + 0.5)
    return s
