"""The statistics of Table 3 (SPEC section 6): the paper's tests and the field's current reporting.

Over 450 lines because it is the one home of every test and interval the reports use: they share the bootstrap, the
clusters and the ranks.

* Normality per cell: the Lilliefors-corrected Kolmogorov-Smirnov test (statsmodels).
* Pairwise comparisons: the two-sided Mann-Whitney U test (scipy), its effect size as the Vargha-Delaney
  A (the probability that a run of the first setup beats a run of the second, ties counted half), and
  Holm's step-down correction over a family of comparisons (statsmodels' operations, checked against it).
* Agarwal et al. (2021): the interquartile mean with a 95% bootstrap confidence interval, and the
  probability of improvement with its interval. A cell of Table 3 is one task, so their stratified
  bootstrap (resampling runs within each task) is the plain bootstrap over the cell's runs. The
  intervals come from scipy's bootstrap (percentile method, a seeded generator, so a report regenerates
  identically): the ``rliable`` library itself does not install with kx's pinned stack (rliable 1.2.0
  wants arch < 8, and arch 7.2.0 fails to import with pandas 3).
* Where a decision rests on the probability of improvement of few runs (the zero-shot study's goal): its studentised
  permutation interval (Brunner and Munzel's statistic over seeded splits of the pooled runs), exact when the two
  samples are alike, where the percentile bootstrap is a little liberal at 10 runs against 10.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import scipy.stats
from statsmodels.stats.diagnostic import lilliefors as _lilliefors

#: bootstrap resamples per interval, and the generator's seed (fixed: a report regenerates identically)
RESAMPLES = 5000
BOOTSTRAP_SEED = 0


def _values(x) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).ravel()
    if a.size and not np.all(np.isfinite(a)):
        raise ValueError(f"values must be finite, got {a[~np.isfinite(a)][:3].tolist()}")
    return a


def lilliefors(x) -> float | None:
    """The Lilliefors test's p-value for normality of ``x`` (``None`` below 4 values or when all are
    equal: the test is undefined)."""
    a = _values(x)
    if a.size < 4 or np.ptp(a) == 0:
        return None
    return float(_lilliefors(a, dist="norm", pvalmethod="table")[1])


@dataclasses.dataclass(frozen=True)
class Comparison:
    """``a`` against ``b``: Mann-Whitney's U (of ``a``) and two-sided p, and the Vargha-Delaney A."""

    n_a: int
    n_b: int
    u: float
    p: float
    a: float  # P(a > b) + P(a = b) / 2: 0.5 no effect; 0.56 / 0.64 / 0.71 small / medium / large (Vargha-Delaney)


def mann_whitney(a, b) -> Comparison:
    """The two-sided Mann-Whitney U test of ``a`` against ``b`` (scipy: exact for small samples without
    ties, else the normal approximation with tie and continuity corrections), with the effect size."""
    x, y = _values(a), _values(b)
    if x.size == 0 or y.size == 0:
        raise ValueError(f"both samples need values, got {x.size} and {y.size}")
    if np.ptp(np.concatenate([x, y])) == 0:  # every value equal: no evidence either way
        return Comparison(x.size, y.size, x.size * y.size / 2, 1.0, 0.5)
    res = scipy.stats.mannwhitneyu(x, y, alternative="two-sided")
    return Comparison(x.size, y.size, float(res.statistic), float(res.pvalue), vargha_delaney(x, y))


def vargha_delaney(a, b) -> float:
    """The Vargha-Delaney A of ``a`` over ``b``: the probability that a value of ``a`` exceeds one of ``b``,
    ties counted half (``U_a / (n_a n_b)``). For one task it is also Agarwal et al.'s probability of
    improvement."""
    x, y = _values(a)[:, None], _values(b)[None, :]
    return float(((x > y).sum() + 0.5 * (x == y).sum()) / (x.size * y.size))


def holm(p) -> np.ndarray:
    """Holm's step-down adjusted p-values of a family (in the given order): ``statsmodels``'
    ``multipletests(p, method="holm")[1]``, the same operations in the same order (the tests compare them bit
    for bit), without its call of ``gc.collect()`` on every family, which took 0.4 s a call in a process holding
    a test suite's compiled programs (a report makes dozens)."""
    p = np.asarray(p, dtype=np.float64)
    if p.size == 0:
        return p
    order = np.argsort(p)
    adjusted = np.maximum.accumulate(p[order] * np.arange(p.size, 0, -1))
    adjusted[adjusted > 1] = 1
    out = np.empty_like(adjusted)
    out[order] = adjusted
    return out


def iqm(x) -> float:
    """The interquartile mean: the mean of the middle 50% (``trim_mean(x, 0.25)``, as rliable's
    ``aggregate_iqm``)."""
    return float(scipy.stats.trim_mean(_values(x), 0.25))


@dataclasses.dataclass(frozen=True)
class Interval:
    value: float
    low: float
    high: float


def _bootstrap(samples, statistic, value: float) -> Interval:
    if min(s.size for s in samples) < 2:  # no spread to resample
        return Interval(value, math.nan, math.nan)
    if np.ptp(np.concatenate(samples)) == 0:
        return Interval(value, value, value)
    res = scipy.stats.bootstrap(samples, statistic, n_resamples=RESAMPLES, confidence_level=0.95, method="percentile",
                                vectorized=True, paired=False, rng=np.random.default_rng(BOOTSTRAP_SEED))
    return Interval(value, float(res.confidence_interval.low), float(res.confidence_interval.high))


def iqm_interval(x) -> Interval:
    """The IQM of ``x`` with its 95% bootstrap interval (runs resampled with replacement)."""
    a = _values(x)
    return _bootstrap((a,), lambda s, axis=-1: scipy.stats.trim_mean(s, 0.25, axis=axis), iqm(a))


def _poi(x, y, axis=-1):
    x, y = np.moveaxis(x, axis, -1), np.moveaxis(y, axis, -1)
    gt = (x[..., :, None] > y[..., None, :]).mean(axis=(-2, -1))
    eq = (x[..., :, None] == y[..., None, :]).mean(axis=(-2, -1))
    return gt + 0.5 * eq


def improvement_interval(a, b) -> Interval:
    """The probability of improvement of ``a`` over ``b`` with its 95% bootstrap interval (each sample's
    runs resampled on their own)."""
    x, y = _values(a), _values(b)
    return _bootstrap((x, y), _poi, vargha_delaney(x, y))


#: permutations of the studentised permutation interval, and its generator's seed (fixed: a report regenerates
#: identically); with the observed split they make 10,000, so the 2.5% tails are whole counts of splits
PERMUTATIONS = 9999
PERMUTATION_SEED = 0


def _placements(v: np.ndarray, pooled: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row of ``v [R, N]`` (a split: its first ``n`` values one sample, the rest the other) with their ranks in
    the pooled sample ``pooled [R, N]``: the Brunner-Munzel effect of the second sample over the first (``P(first <
    second) + P(equal) / 2``), its studentised statistic ``sqrt(N) (effect - 1/2) / sigma`` and ``sigma^2``, Brunner
    and Munzel's variance of the placements (floored at ``N / (2 n m)`` where it is zero, as Neubert and Brunner
    (2007) do: a complete separation or one value per sample)."""
    N = v.shape[1]
    m = N - n
    first = (pooled[:, :n] - scipy.stats.rankdata(v[:, :n], axis=1)) / m
    second = (pooled[:, n:] - scipy.stats.rankdata(v[:, n:], axis=1)) / n
    sigma2 = N * (first.var(axis=1, ddof=1) / n + second.var(axis=1, ddof=1) / m)
    sigma2 = np.where(sigma2 > 0, sigma2, N / (2 * n * m))
    effect = second.mean(axis=1)
    return effect, math.sqrt(N) * (effect - 0.5) / np.sqrt(sigma2), sigma2


def improvement_permutation_interval(a, b, permutations: int = PERMUTATIONS, level: float = 0.95) -> Interval:
    """The probability of improvement of ``a`` over ``b`` (ties half) with its studentised permutation interval
    (Neubert and Brunner 2007; Pauly, Asendorf and Konietschke 2016): the Brunner-Munzel statistic's distribution
    over ``permutations`` random splits of the pooled runs, seeded, in place of its t approximation.

    Its bounds are ``p - c * se``, with ``c`` the split statistics' order statistics that make the interval the
    inversion of the Monte Carlo permutation test with the observed split counted among them: with 9,999
    permutations, a lower bound above 0.5 says that fewer than 250 of them reach the observed statistic, so under
    exchangeable runs (the two learners alike) it happens at most 2.5% of the time, ties and all, at any sample
    size; for unlike spreads the studentisation keeps it asymptotically right. The percentile bootstrap of
    :func:`improvement_interval` rejects 2.75-3.7% at 2.5% on 10 runs against 10 shaped like the zero-shot study's
    (``tests/test_zeroshot.py``). Clipped to [0, 1]; ``nan`` bounds below two runs a sample.

    ``b`` over ``a`` is ``a`` over ``b`` mirrored (``1 - high, 1 - low``: each split's statistic changes sign), so a
    table of both directions agrees with itself; each pair is computed once a process (cached)."""
    x, y = _values(a), _values(b)
    if (y.size, y.tobytes()) < (x.size, x.tobytes()):
        i = _permutation_interval(y.tobytes(), x.tobytes(), permutations, level)
        return Interval(vargha_delaney(x, y), 1 - i.high, 1 - i.low)
    return _permutation_interval(x.tobytes(), y.tobytes(), permutations, level)


@functools.lru_cache(maxsize=4096)
def _permutation_interval(a: bytes, b: bytes, permutations: int, level: float) -> Interval:
    """:func:`improvement_permutation_interval` of ``a`` over ``b`` (float64 bytes)."""
    x, y = np.frombuffer(b), np.frombuffer(a)
    value = vargha_delaney(y, x)
    if min(x.size, y.size) < 2:
        return Interval(value, math.nan, math.nan)
    both = np.concatenate([x, y])
    if np.ptp(both) == 0:
        return Interval(value, value, value)
    N = both.size
    k = int(math.floor((1 - level) / 2 * (permutations + 1) + 1e-9))
    if k < 1:
        raise ValueError(f"permutations={permutations} is too few for a {level:.0%} interval: need "
                         f"{math.ceil(2 / (1 - level)) - 1} or more")
    rng = np.random.default_rng(PERMUTATION_SEED)
    splits = np.concatenate([np.arange(N)[None], rng.permuted(np.tile(np.arange(N), (permutations, 1)), axis=1)])
    pooled = scipy.stats.rankdata(both)
    _, t, sigma2 = _placements(both[splits], pooled[splits], x.size)
    t = np.round(t, 9)  # one split's statistic, summed in another order, must tie with itself
    ordered = np.sort(t[1:])
    high_c, low_c = ordered[-k], ordered[k - 1]  # the k-th largest and k-th smallest of the permuted splits
    se = math.sqrt(sigma2[0] / N)
    # 0.5 + (t - c) se rather than p - c se: the lower bound is above 0.5 exactly when the test rejects
    low, high = 0.5 + (t[0] - high_c) * se, 0.5 + (t[0] - low_c) * se
    return Interval(value, float(min(max(low, 0.0), 1.0)), float(min(max(high, 0.0), 1.0)))


def mean_band(curves) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column of ``curves`` (runs of generations, cut to the shortest run): the mean and its 95% band
    (Student's t on the standard error; zero width with one run)."""
    n_gen = min(len(c) for c in curves)
    c = np.asarray([list(c)[:n_gen] for c in curves], dtype=np.float64)
    mean = c.mean(axis=0)
    n = c.shape[0]
    if n < 2:
        return mean, mean.copy(), mean.copy()
    half = scipy.stats.t.ppf(0.975, n - 1) * c.std(axis=0, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half


# ------------------------------------------------------------------------ pooled over targets, and power

#: resamples of the power estimate at each run count
POWER_RESAMPLES = 1000


def _ranks_and_ties(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``x [R, n]`` against ``y [R, m]``: the sum of ``x``'s midranks in the pooled row, and the
    tie term ``sum(t^3 - t)`` over the pooled row's groups of equal values."""
    both = np.concatenate([x, y], axis=-1)
    ranks = scipy.stats.rankdata(both, axis=-1)
    s = np.sort(both, axis=-1)
    rows, width = s.shape
    group = np.concatenate([np.zeros((rows, 1), np.int64), np.cumsum(s[:, 1:] != s[:, :-1], axis=-1)], axis=-1)
    counts = np.bincount((np.arange(rows)[:, None] * width + group).ravel(), minlength=rows * width)
    counts = counts.reshape(rows, width).astype(np.float64)
    return ranks[:, :x.shape[1]].sum(axis=-1), (counts**3 - counts).sum(axis=-1)


def van_elteren_z(strata: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """van Elteren's z (:func:`van_elteren`) of ``R`` data sets at once, over strata of ``(x [R, n_t], y [R,
    m_t])``: ``[R]``, NaN where no stratum varies."""
    num = den = 0.0
    for x, y in strata:
        n, m = x.shape[-1], y.shape[-1]
        big = n + m
        w, ties = _ranks_and_ties(x, y)
        var = n * m / 12.0 * ((big + 1) - ties / (big * (big - 1)))
        weight = 1.0 / (big + 1)
        num = num + weight * (w - n * (big + 1) / 2.0)
        den = den + weight**2 * var
    den = np.asarray(den, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.sqrt(np.where(den > 0, den, 1.0)), np.nan)


@dataclasses.dataclass(frozen=True)
class Pooled:
    """``a`` against ``b`` over strata (targets): van Elteren's z and two-sided p, the probability of
    improvement averaged over the strata with its stratified-bootstrap 95% interval, and the mean of the
    strata's mean differences."""

    strata: int
    n_a: tuple[int, ...]
    n_b: tuple[int, ...]
    z: float
    p: float
    poi: Interval
    diff: float


def _strata(a_by, b_by) -> list[tuple[np.ndarray, np.ndarray]]:
    strata = [(_values(a), _values(b)) for a, b in zip(a_by, b_by, strict=True)]
    if not strata or any(a.size == 0 or b.size == 0 for a, b in strata):
        sizes = [(a.size, b.size) for a, b in strata]
        raise ValueError(f"every stratum needs values in both samples, got sizes {sizes}")
    return strata


def van_elteren(a_by, b_by) -> Pooled:
    """van Elteren's stratified rank-sum test of ``a`` against ``b``, one stratum per pair ``(a_by[t],
    b_by[t])`` (a target's runs of two setups): the Wilcoxon rank-sum statistics of the strata (midranks),
    weighted by ``1 / (N_t + 1)`` (``N_t`` the stratum's runs), summed and standardised with the tie-corrected
    variance; two-sided p from the normal distribution, no continuity correction (one stratum: scipy's
    asymptotic Mann-Whitney test without it). p is 1 where no stratum has two different values."""
    strata = _strata(a_by, b_by)
    z = float(van_elteren_z([(a[None], b[None]) for a, b in strata])[0])
    p = 1.0 if math.isnan(z) else float(2 * scipy.stats.norm.sf(abs(z)))
    return Pooled(len(strata), tuple(a.size for a, _ in strata), tuple(b.size for _, b in strata),
                  0.0 if math.isnan(z) else z, p, pooled_improvement(a_by, b_by),
                  float(np.mean([a.mean() - b.mean() for a, b in strata])))


def pooled_improvement(a_by, b_by) -> Interval:
    """The probability of improvement of ``a`` over ``b`` averaged over the strata, with its stratified
    bootstrap 95% interval (each cell's runs resampled on their own, as rliable does per task)."""
    strata = _strata(a_by, b_by)
    flat = tuple(v for pair in strata for v in pair)

    def stat(*samples, axis=-1):
        return np.mean([_poi(samples[2 * i], samples[2 * i + 1], axis=axis) for i in range(len(samples) // 2)], axis=0)

    value = float(np.mean([vargha_delaney(a, b) for a, b in strata]))
    return _bootstrap(flat, stat, value)


def power(a_by, b_by, level: float, runs: int | None = None, resamples: int = POWER_RESAMPLES,
          seed: int = BOOTSTRAP_SEED, direction: int = 0) -> float:
    """The probability that :func:`van_elteren` gives p < ``level`` at the observed effect: every cell's runs
    resampled with replacement to ``runs`` runs (``None``: each cell's own count), ``resamples`` times.
    ``direction`` +1 or -1: only significance with z of that sign counts (the observed direction); 0:
    either."""
    if direction not in (-1, 0, 1):
        raise ValueError(f"direction: allowed -1, 0, 1, got {direction!r}")
    strata = _strata(a_by, b_by)
    rng = np.random.default_rng(seed)
    draw = lambda v: v[rng.integers(0, v.size, size=(resamples, runs or v.size))]  # noqa: E731
    z = np.nan_to_num(van_elteren_z([(draw(a), draw(b)) for a, b in strata]))
    p = 2 * scipy.stats.norm.sf(np.abs(z))
    way = np.ones_like(z, bool) if direction == 0 else (np.sign(z) == direction)
    return float(((p < level) & way).mean())


def runs_needed(a_by, b_by, level: float, goal: float, candidates, direction: int = 0) -> int | None:
    """The smallest run count of ``candidates`` (ascending) at which :func:`power` reaches ``goal``; ``None``
    if none does."""
    for n in candidates:
        if power(a_by, b_by, level, runs=n, direction=direction) >= goal:
            return int(n)
    return None


# ---------------------------------------------------- pooled over targets that share sources: clusters as the unit
#
# A cell's runs are a matrix ``[clusters, strata]``: row ``i`` holds a cluster's value in each target (NaN where it has
# no run there). In a transfer cell of a protocol whose targets share sources, run ``i`` of every target descends
# from source ``i``: one row, correlated across its columns. In a cell of independent runs (no transfer, or a source
# of its own per target run) every run is a cluster of its own: one value a row. Rows are independent; the columns
# of one row need not be.

#: bootstrap resamples of the clustered interval of the averaged probability of improvement
CLUSTER_RESAMPLES = 2000


def cluster_matrix(by_target: list[dict], shared: bool) -> np.ndarray:
    """A cell as ``[clusters, strata]``: ``by_target[t]`` maps a run index to its value in stratum ``t``. ``shared``:
    run ``i`` of every stratum is one cluster (they share source ``i``); else every run is a cluster of its own."""
    strata = len(by_target)
    if shared:
        runs = sorted(set().union(*[set(d) for d in by_target]))
        out = np.full((len(runs), strata), np.nan)
        for t, d in enumerate(by_target):
            for i, r in enumerate(runs):
                if r in d:
                    out[i, t] = d[r]
    else:
        rows = [(t, v) for t, d in enumerate(by_target) for _, v in sorted(d.items())]
        out = np.full((len(rows), strata), np.nan)
        for i, (t, v) in enumerate(rows):
            out[i, t] = v
    if out.size and not np.all(np.isfinite(out[~np.isnan(out)])):
        raise ValueError("values must be finite")
    return out


def _check_cells(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or a.shape[1] == 0:
        raise ValueError(f"cells must be [clusters, strata] with the same strata, got shapes {a.shape} and {b.shape}")
    have_a, have_b = (~np.isnan(a)).sum(0), (~np.isnan(b)).sum(0)
    if np.any(have_a == 0) or np.any(have_b == 0):
        raise ValueError(f"every stratum needs values in both cells, got runs {have_a.tolist()} and {have_b.tolist()}")
    return a, b


def _clustered_parts(x: np.ndarray, y: np.ndarray):
    """For data sets ``x [R, Ca, T]`` and ``y [R, Cb, T]`` (NaN: no run): van Elteren's centred statistic ``[R]``,
    each cell's part of its cluster-robust variance and degrees of freedom ``[R]``, and the probability of
    improvement averaged over the strata ``[R]``.

    The statistic is ``sum_t w_t (W_t - n_t (N_t + 1) / 2)``, ``W_t`` the sum of ``x``'s midranks among the ``N_t =
    n_t + m_t`` runs of stratum ``t`` and ``w_t = 1 / (N_t + 1)`` van Elteren's weight. With a run's rank score
    ``s = R - (N_t + 1) / 2`` (they sum to zero over a stratum) it is the difference of the two cells' score sums,
    ``sum_t w_t (m_t / N_t) sum_x s - sum_t w_t (n_t / N_t) sum_y s``: each cell's part is a sum over its clusters of
    their runs' terms, summed over the strata, so its variance is estimated from the clusters' sums (Liang & Zeger's
    sandwich with clusters as the unit; for rank scores Rosner, Glynn & Lee 2006): ``C / (C - 1)`` times the sum of
    the squared deviations of the clusters' sums from their group's mean, per group of clusters with runs in the same
    strata (:func:`_groups`). A cluster's correlation across the strata thus enters its variance; with one run a
    cluster and equal distributions it is the permutation variance's large-sample value."""
    num = np.zeros(x.shape[0])
    za = np.zeros(x.shape[:2])
    zb = np.zeros(y.shape[:2])
    poi = np.zeros(x.shape[0])
    strata = x.shape[-1]
    for t in range(strata):
        # only the rows with a run in this stratum in some data set (independent runs: a third of a cell's rows)
        ka, kb = np.flatnonzero((~np.isnan(x[..., t])).any(0)), np.flatnonzero((~np.isnan(y[..., t])).any(0))
        xt, yt = x[:, ka, t], y[:, kb, t]
        mx, my = ~np.isnan(xt), ~np.isnan(yt)
        n, m = mx.sum(-1).astype(np.float64), my.sum(-1).astype(np.float64)
        big = n + m
        ranks = scipy.stats.rankdata(np.concatenate([xt, yt], axis=-1), axis=-1, nan_policy="omit")
        score = np.nan_to_num(ranks - (big[:, None] + 1) / 2)  # absent runs: 0
        sx, sy = score[:, :ka.size], score[:, ka.size:]
        w = 1.0 / (big + 1.0)
        num += w * sx.sum(-1)
        za[:, ka] += np.where(mx, (w * m / big)[:, None] * sx, 0.0)
        zb[:, kb] += np.where(my, -(w * n / big)[:, None] * sy, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            poi += (sx.sum(-1) + n * m / 2) / (n * m) / strata  # U / (n m), U = W - n (n + 1) / 2
    va, dfa = _cell_variance(za, x)
    vb, dfb = _cell_variance(zb, y)
    return num, va, vb, dfa, dfb, poi


def _cell_variance(z: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A cell's part of the variance from its clusters' contributions ``z [R, C]``, and its degrees of freedom: per
    group of clusters with runs in the same strata (:func:`_groups`: one group for complete shared clusters, one a
    stratum for independent runs), ``C_g / (C_g - 1)`` times the sum of the squared deviations of the group's
    contributions from their mean, and Welch-Satterthwaite's degrees of freedom over the groups' parts. The groups are
    those of the first data set's pattern of runs (resamples keep it: :func:`resample_clusters`)."""
    var = np.zeros(z.shape[0])
    parts = []
    for g in _groups(cells[0]):
        c = float(g.size)
        dev = z[:, g] - z[:, g].mean(-1, keepdims=True)
        part = c / (c - 1) * (dev**2).sum(-1) if c > 1 else np.full(z.shape[0], np.nan)
        var = var + part
        parts.append((part, c - 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        df = var**2 / sum(p**2 / d if d > 0 else np.nan for p, d in parts)
    return var, df


def clustered_z(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The clustered van Elteren statistic of data sets ``x [R, Ca, T]`` against ``y [R, Cb, T]``: ``(t [R], df [R])``,
    the statistic over its cluster-robust standard error and the degrees of freedom of its reference t distribution
    (Welch-Satterthwaite over the two cells' parts, each with its clusters less one). ``t`` is NaN where the
    variance is zero (nothing varies)."""
    num, va, vb, dfa, dfb, _ = _clustered_parts(x, y)
    var = va + vb
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(var > 0, num / np.sqrt(np.where(var > 0, var, 1.0)), np.nan)
        df = np.where(var > 0, var**2 / (va**2 / dfa + vb**2 / dfb), np.nan)
    return t, df


def clustered_p(t: np.ndarray, df: np.ndarray) -> np.ndarray:
    """Two-sided p of :func:`clustered_z`'s statistic: Student's t with its degrees of freedom (1 where it is NaN)."""
    t, df = np.asarray(t, np.float64), np.asarray(df, np.float64)
    with np.errstate(invalid="ignore"):
        p = 2 * scipy.stats.t.sf(np.abs(t), np.where(np.isnan(df), 1.0, df))
    return np.where(np.isnan(t), 1.0, p)


@dataclasses.dataclass(frozen=True)
class Clustered:
    """``a`` against ``b`` over strata with clusters as the unit (:func:`clustered_van_elteren`): the statistic, its
    degrees of freedom and two-sided p, the normal deviate of that p (signed: what a group-sequential boundary
    reads), the averaged probability of improvement with its cluster-bootstrap 95% interval, the mean of the strata's
    mean differences, each cell's clusters and runs a stratum, and, where there is no statistic (``z`` 0, ``df`` NaN,
    ``p`` 1), why not."""

    strata: int
    clusters: tuple[int, int]
    n_a: tuple[int, ...]
    n_b: tuple[int, ...]
    z: float
    df: float
    p: float
    z_equivalent: float
    poi: Interval
    diff: float
    why: str = ""


#: why a :class:`Clustered` has no statistic: a cluster whose runs are in a pattern of strata no other cluster of its
#: cell shares leaves its group's part of the variance with no degrees of freedom, and so the whole variance unknown
LONE_CLUSTER = "not estimable: a cluster alone in its pattern of targets"
#: why not, when every run of both cells has the same rank score in every stratum
NOTHING_VARIES = "nothing varies"


def clustered_van_elteren(a: np.ndarray, b: np.ndarray) -> Clustered:
    """van Elteren's stratified rank-sum statistic of cell ``a`` against cell ``b`` (each ``[clusters, strata]``:
    :func:`cluster_matrix`) with a cluster-robust variance, so that it holds its level when a cluster's runs in
    several strata are correlated (targets transferred from one source): t reference with Welch-Satterthwaite
    degrees of freedom, two-sided. With one run a cluster it is van Elteren's statistic with the placements'
    variance instead of the permutation variance. Where the variance cannot be estimated (:data:`LONE_CLUSTER`) or is
    zero (:data:`NOTHING_VARIES`) there is no statistic: ``z`` 0, ``df`` NaN, ``p`` 1, and ``why`` says which."""
    a, b = _check_cells(a, b)
    t, df = clustered_z(a[None], b[None])
    t, df = float(t[0]), float(df[0])
    p = float(clustered_p(np.array([t]), np.array([df]))[0])
    zeq = 0.0 if math.isnan(t) else math.copysign(float(scipy.stats.norm.isf(p / 2)), t)
    diffs = [np.nanmean(a[:, s]) - np.nanmean(b[:, s]) for s in range(a.shape[1])]
    why = ""
    if math.isnan(t):
        why = LONE_CLUSTER if any(g.size == 1 for cell in (a, b) for g in _groups(cell)) else NOTHING_VARIES
    return Clustered(a.shape[1], (int((~np.isnan(a)).any(1).sum()), int((~np.isnan(b)).any(1).sum())),
                     tuple(int(v) for v in (~np.isnan(a)).sum(0)), tuple(int(v) for v in (~np.isnan(b)).sum(0)),
                     0.0 if math.isnan(t) else t, df, p, zeq, clustered_improvement(a, b), float(np.mean(diffs)), why)


def leave_out_lone_clusters(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Cells ``a`` and ``b`` (``[clusters, strata]``) without the clusters alone in their pattern of strata
    (:data:`LONE_CLUSTER`), and how many each left out: a source that has run in some of the targets while no other
    has run in just those (a protocol that runs a source's targets one after another, between its first target run
    and its last). Such a cluster leaves its group's part of the variance with no degrees of freedom, so with it the
    test has no statistic; without it the test is the same test on the other clusters, which the next look reads
    again with it. Which runs exist decides, never their values, so the test keeps its level (tests/test_clustered.py
    checks it on data shaped like PPO's Table 3 cells). Nothing is left out, and the test says why it has no statistic,
    where leaving the lone clusters out would leave a cell with no run in some stratum (independent runs, one of them
    in a stratum) or none at all."""
    a, b = _check_cells(a, b)
    out, left = [], []
    for cell in (a, b):
        lone = [int(g[0]) for g in _groups(cell) if g.size == 1]
        kept = np.delete(cell, lone, axis=0)
        whole = bool(lone) and bool(np.all((~np.isnan(kept)).sum(0) > 0))  # no stratum (nor the cell) emptied
        out.append(kept if whole else cell)
        left.append(len(lone) if whole else 0)
    return out[0], out[1], (left[0], left[1])


def _groups(cell: np.ndarray) -> list[np.ndarray]:
    """A cell's clusters grouped by the strata they have runs in (one group for complete shared clusters; one per
    stratum for independent runs): the bootstrap resamples within each group, so a resample keeps a stratified
    design's runs a stratum."""
    present = ~np.isnan(cell)
    patterns: dict[bytes, list[int]] = {}
    for i, row in enumerate(present):
        patterns.setdefault(row.tobytes(), []).append(i)
    return [np.asarray(v) for v in patterns.values()]


def resample_clusters(cell: np.ndarray, rng: np.random.Generator, resamples: int,
                      runs: int | None = None) -> np.ndarray:
    """``[resamples, clusters, strata]``: the cell's clusters drawn with replacement within each group of
    :func:`_groups`, each group to its own size (``runs`` None) or to ``runs`` times its share of the largest group
    (``runs`` a stratum for independent runs, ``runs`` clusters for complete shared ones)."""
    groups = _groups(cell)
    largest = max(g.size for g in groups)
    parts = []
    for g in groups:
        k = g.size if runs is None else max(1, round(runs * g.size / largest))
        parts.append(g[rng.integers(0, g.size, size=(resamples, k))])
    return cell[np.concatenate(parts, axis=1)]


def clustered_improvement(a: np.ndarray, b: np.ndarray, resamples: int = CLUSTER_RESAMPLES,
                          seed: int = BOOTSTRAP_SEED) -> Interval:
    """The probability of improvement of ``a`` over ``b`` averaged over the strata, with its 95% percentile
    interval from a bootstrap that resamples whole clusters within each cell (and within each stratum where a
    cell's runs are independent)."""
    a, b = _check_cells(a, b)
    value = float(_clustered_parts(a[None], b[None])[-1][0])
    both = np.concatenate([a, b])
    if np.ptp(both[~np.isnan(both)]) == 0:
        return Interval(value, value, value)
    if min(g.size for g in _groups(a) + _groups(b)) < 2:
        return Interval(value, math.nan, math.nan)
    rng = np.random.default_rng(seed)
    vals = []
    for lo in range(0, resamples, 500):  # in blocks: a block's comparisons stay in memory
        k = min(500, resamples - lo)
        vals.append(_clustered_parts(resample_clusters(a, rng, k), resample_clusters(b, rng, k))[-1])
    low, high = np.percentile(np.concatenate(vals), [2.5, 97.5])
    return Interval(value, float(low), float(high))


def clustered_power(a: np.ndarray, b: np.ndarray, level: float, runs: int | None = None,
                    resamples: int = POWER_RESAMPLES, seed: int = BOOTSTRAP_SEED, direction: int = 0) -> float:
    """The probability that :func:`clustered_van_elteren` gives p < ``level`` at the observed effect: each cell's
    clusters resampled with replacement (:func:`resample_clusters`, to ``runs`` runs a cell, or its own count),
    ``resamples`` times. ``direction`` +1 or -1: only significance with that sign counts; 0: either."""
    if direction not in (-1, 0, 1):
        raise ValueError(f"direction: allowed -1, 0, 1, got {direction!r}")
    a, b = _check_cells(a, b)
    rng = np.random.default_rng(seed)
    hits = 0
    for lo in range(0, resamples, 250):
        k = min(250, resamples - lo)
        t, df = clustered_z(resample_clusters(a, rng, k, runs), resample_clusters(b, rng, k, runs))
        p = clustered_p(t, df)
        way = np.ones_like(p, bool) if direction == 0 else (np.sign(np.nan_to_num(t)) == direction)
        hits += int(((p < level) & way).sum())
    return hits / resamples


def clustered_runs_needed(a: np.ndarray, b: np.ndarray, level: float, goal: float, candidates,
                          direction: int = 0) -> int | None:
    """The smallest run count of ``candidates`` (ascending) at which :func:`clustered_power` reaches ``goal``;
    ``None`` if none does."""
    for n in candidates:
        if clustered_power(a, b, level, runs=n, direction=direction) >= goal:
            return int(n)
    return None
