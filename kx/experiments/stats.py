"""The statistics of Table 3 (SPEC section 6): the paper's tests and the field's current reporting.

* Normality per cell: the Lilliefors-corrected Kolmogorov-Smirnov test (statsmodels).
* Pairwise comparisons: the two-sided Mann-Whitney U test (scipy), its effect size as the Vargha-Delaney
  A (the probability that a run of the first setup beats a run of the second, ties counted half), and
  Holm's step-down correction over a family of comparisons (statsmodels).
* Agarwal et al. (2021): the interquartile mean with a 95% bootstrap confidence interval, and the
  probability of improvement with its interval. A cell of Table 3 is one task, so their stratified
  bootstrap (resampling runs within each task) is the plain bootstrap over the cell's runs. The
  intervals come from scipy's bootstrap (percentile method, a seeded generator, so a report regenerates
  identically): the ``rliable`` library itself does not install with kx's pinned stack (rliable 1.2.0
  wants arch < 8, and arch 7.2.0 fails to import with pandas 3).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.stats
from statsmodels.stats.diagnostic import lilliefors as _lilliefors
from statsmodels.stats.multitest import multipletests

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


def smallest_p(n_a: int, n_b: int) -> float:
    """The smallest two-sided p :func:`mann_whitney` gives for samples of ``n_a`` and ``n_b`` distinct
    values, reached when every value of one sample exceeds every value of the other: ``2 / C(n_a + n_b,
    n_a)`` where scipy's test is exact (a sample of at most 8 values), the normal approximation's beyond. It
    bounds what a protocol of that many runs per cell can show (ties between runs, rare in fitness
    values, can lower the approximation's p a little further)."""
    if n_a < 1 or n_b < 1:
        raise ValueError(f"both samples need values, got {n_a} and {n_b}")
    return mann_whitney(np.arange(n_a) + float(n_b), np.arange(n_b, dtype=np.float64)).p


def vargha_delaney(a, b) -> float:
    """The Vargha-Delaney A of ``a`` over ``b``: the probability that a value of ``a`` exceeds one of ``b``,
    ties counted half (``U_a / (n_a n_b)``). For one task it is also Agarwal et al.'s probability of
    improvement."""
    x, y = _values(a)[:, None], _values(b)[None, :]
    return float(((x > y).sum() + 0.5 * (x == y).sum()) / (x.size * y.size))


def holm(p) -> np.ndarray:
    """Holm's step-down adjusted p-values of a family (in the given order)."""
    p = np.asarray(p, dtype=np.float64)
    if p.size == 0:
        return p
    return multipletests(p, method="holm")[1]


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


def mean_band(curves) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column of ``curves`` [runs, generations]: the mean and its 95% band (Student's t on the
    standard error; zero width with one run)."""
    c = np.asarray(curves, dtype=np.float64)
    mean = c.mean(axis=0)
    n = c.shape[0]
    if n < 2:
        return mean, mean.copy(), mean.copy()
    half = scipy.stats.t.ppf(0.975, n - 1) * c.std(axis=0, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half
