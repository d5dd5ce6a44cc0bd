"""The looks of a protocol paid for: a group-sequential plan fixed in advance, and Holm's correction over its
comparisons.

A comparison may be tested at several looks, each at a planned number of runs a cell (``looks``, ascending; the
last the most the plan allows). Its test statistic at look ``k``, as a normal deviate ``z_k`` (the two-sided p of
the pooled test turned back into a deviate), is compared with a boundary ``c_k``: the boundaries spend the level
over the looks by Lan & DeMets' (1983) alpha-spending function of O'Brien-Fleming type, two-sided,

    alpha(t) = 2 - 2 Phi(Phi^-1(1 - alpha / 2) / sqrt(t)),   t = runs at the look / runs at the last look,

so that under the null the chance to cross any boundary up to look ``k`` is ``alpha(t_k)``, with the looks'
deviates correlated as a Brownian motion's (``corr(z_j, z_k) = sqrt(t_j / t_k)``; Jennison & Turnbull 2000,
chapter 7). A comparison that stops early (no more runs were added to its cells) is decided at the last look it had,
with that look's boundary, and so is a plan's more lenient choice never taken after the data; which looks a
comparison had may depend on the data (adding runs where power is short): a stop only removes chances to reject,
so the level holds whatever the choice.

Holm over a family of such comparisons: each comparison's *sequential p-value* (the smallest level at which its
plan would have rejected at one of the looks it had) goes into Holm's step-down procedure, which is then the
closed test of weighted-Bonferroni group-sequential tests (Maurer & Bretz 2013, "Multiple testing in group
sequential trials using graphical approaches", Statistics in Biopharmaceutical Research 5(4)): a rejection's
level passes to the others, at every look.

The crossing probabilities are integrated numerically on a fixed grid (deterministic: a report regenerates
identically).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.optimize
import scipy.stats

SPENDING = "obrien_fleming"
#: the grid of the numerical integration (points over the continuation region of a look)
GRID = 401


def spent(alpha: float, t: float) -> float:
    """The level spent by information fraction ``t`` (0 < t <= 1): Lan & DeMets' O'Brien-Fleming-type function,
    two-sided."""
    if not 0 < t <= 1:
        raise ValueError(f"information fraction: allowed 0 < t <= 1, got {t!r}")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha: allowed 0 < alpha < 1, got {alpha!r}")
    return float(2 - 2 * scipy.stats.norm.cdf(scipy.stats.norm.isf(alpha / 2) / math.sqrt(t)))


def fractions(looks) -> tuple[float, ...]:
    """The information fractions of ``looks`` (runs a cell at each look, ascending)."""
    looks = [int(v) for v in looks]
    if not looks or any(v < 1 for v in looks) or any(b <= a for a, b in zip(looks, looks[1:])):
        raise ValueError(f"looks: allowed ascending run counts >= 1, got {looks}")
    return tuple(v / looks[-1] for v in looks)


@functools.lru_cache(maxsize=4096)
def boundaries(alpha: float, fracs: tuple[float, ...]) -> tuple[float, ...]:
    """The two-sided boundaries ``|z| >= c_k`` of the looks at information fractions ``fracs`` (ascending, the last
    at most 1), spending ``alpha`` by :func:`spent`."""
    if any(b <= a for a, b in zip(fracs, fracs[1:])):
        raise ValueError(f"information fractions: allowed ascending, got {fracs}")
    out: list[float] = []
    grid = dens = None  # the density over the region not yet crossed (:func:`_continue`)
    prev_t, prev_spent = 0.0, 0.0
    for t in fracs:
        goal = spent(alpha, t) - prev_spent
        if grid is None:
            c = float(scipy.stats.norm.isf(goal / 2))
        else:
            sd = math.sqrt(t - prev_t)
            w = _weights(grid)

            def crossing(c, grid=grid, dens=dens, sd=sd, w=w, t=t):
                b = c * math.sqrt(t)
                stay = scipy.stats.norm.cdf((b - grid) / sd) - scipy.stats.norm.cdf((-b - grid) / sd)
                return float(np.sum(w * dens * (1 - stay))) - goal

            c = float(scipy.optimize.brentq(crossing, 0.0, 40.0, xtol=1e-12))
        out.append(c)
        grid, dens = _continue(grid, dens, prev_t, t, c)
        prev_t, prev_spent = t, spent(alpha, t)
    return tuple(out)


def _continue(grid, dens, prev_t: float, t: float, c: float) -> tuple[np.ndarray, np.ndarray]:
    """The density of the score ``S = z sqrt(t)`` at look ``t`` on a grid over the region not crossed, ``|S| <
    c sqrt(t)``: from the previous look's (``grid`` None: the first look) by the Brownian increment over ``t -
    prev_t``."""
    b = c * math.sqrt(t)
    new = np.linspace(-b, b, GRID)
    if grid is None:
        return new, scipy.stats.norm.pdf(new / math.sqrt(t)) / math.sqrt(t)
    sd = math.sqrt(t - prev_t)
    return new, (_weights(grid) * dens * scipy.stats.norm.pdf((new[:, None] - grid[None, :]) / sd) / sd).sum(-1)


def _weights(grid: np.ndarray) -> np.ndarray:
    """Simpson's weights on an evenly spaced grid of an odd number of points."""
    h = grid[1] - grid[0]
    w = np.ones(grid.size)
    w[1:-1:2], w[2:-1:2] = 4, 2
    return w * h / 3


def crossing_probability(alpha: float, fracs: tuple[float, ...]) -> float:
    """The chance under the null of crossing a boundary of :func:`boundaries` at any look (``spent(alpha, t_K)``
    by construction; a check of the integration)."""
    grid = dens = None
    prev = 0.0
    for t, c in zip(fracs, boundaries(alpha, tuple(fracs))):
        grid, dens = _continue(grid, dens, prev, t, c)
        prev = t
    return 1.0 - float(np.sum(_weights(grid) * dens))


def sequential_p(z_by_look, fracs: tuple[float, ...]) -> float:
    """A comparison's sequential p-value: the smallest level at which the plan of information fractions ``fracs``
    rejects at one of the looks it had (``z_by_look``: its deviates at the first ``len(z_by_look)`` looks; a look
    it did not have is left out at the end). Monotone in every ``|z|``; 1 where none is finite."""
    z = [abs(float(v)) for v in z_by_look]
    if not z or len(z) > len(fracs):
        raise ValueError(f"a comparison's looks: allowed 1 to {len(fracs)} deviates, got {len(z)}")
    if not any(math.isfinite(v) and v > 0 for v in z):
        return 1.0
    full = tuple(float(f) for f in fracs)  # the plan's looks: a comparison that stopped early reads their boundaries

    def excess(a):
        c = boundaries(a, full)
        return max(zk - ck for zk, ck in zip(z, c))

    hi = 1 - 1e-12
    if excess(hi) < 0:
        return 1.0
    lo = 1e-9  # below it the report prints "<0.0001" all the same
    if excess(lo) >= 0:
        return lo
    return float(scipy.optimize.brentq(excess, lo, hi, xtol=1e-14, rtol=1e-10))
