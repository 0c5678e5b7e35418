"""The benchmark's statistics: point estimates and 95 % bootstrap intervals (scipy.stats.bootstrap).

Every metric is computed on the pooled episodes of a controller: for a fixed controller the
held-out plants, for an agent its training seeds x the same plants. Intervals are bootstrap
intervals with the training seeds as strata: `scipy.stats.bootstrap` gets one sample per seed and
resamples the plants within each (for a fixed controller, one sample: the plain bootstrap over
plants). Paired comparisons (the difference to `pid-robust`, the normalised score) resample the
plants jointly for every seed and the reference, so each plant meets itself. BCa intervals with
2000 resamples from a fixed generator (the same inputs give the same interval); the worst episode's
interval is a percentile interval (BCa is undefined for a maximum).

The spread over training seeds is reported beside the intervals (`per_seed`), not folded into
them: with 3-5 seeds a bootstrap over seeds says little.
"""

from __future__ import annotations

import math
import warnings
from typing import Callable, Sequence

import numpy as np

from millvib_env._checks import integer, real, shown

__all__ = ["cvar", "iqm", "worst", "METRICS", "BOOTSTRAP", "BOOTSTRAP_SEED", "interval", "paired_difference",
           "normalized_score", "load_library"]

#: bootstrap settings of every interval (scipy.stats.bootstrap)
BOOTSTRAP = {"n_resamples": 2000, "confidence_level": 0.95}
BOOTSTRAP_SEED = 12345


def load_library() -> None:
    """Import scipy.stats now (scipy builds its functions' docstrings at import: docs/performance.md), so that a caller
    with time to spare (a benchmark whose worker processes are starting) does not pay it at its first interval."""
    import scipy.stats  # noqa: F401


def _values(values, axis: int) -> np.ndarray:
    """`values` as floats with at least one along `axis`: an episode's cost may be inf (a diverged one whose
    record was not finite), never NaN, so a NaN or an empty sample is refused rather than giving a NaN."""
    try:
        v = np.asarray(values, dtype=float)
    except (TypeError, ValueError, OverflowError):
        v = np.empty(0)
    if v.ndim == 0 or v.size == 0 or np.isnan(v).any():
        raise ValueError(f"values = {shown(values)} is invalid: numbers, at least one (inf allowed, NaN not)")
    integer("axis", axis, lo=-v.ndim, hi=v.ndim - 1)
    return v


def cvar(values, worst_fraction: float = 0.2, axis: int = -1):
    """Mean of the worst (largest) `worst_fraction` of the values (at least one), along `axis`."""
    worst_fraction = real("worst_fraction", worst_fraction, lo=0.0, lo_open=True, hi=1.0)
    v = -np.sort(-_values(values, axis), axis=axis)
    k = max(1, int(math.ceil(worst_fraction * v.shape[axis])))
    out = np.mean(np.take(v, np.arange(k), axis=axis), axis=axis)
    return float(out) if np.ndim(out) == 0 else out


def iqm(values, axis: int = -1):
    """Interquartile mean: the mean of the middle 50 % (scipy.stats.trim_mean, 25 % cut each side)."""
    from scipy import stats

    out = stats.trim_mean(_values(values, axis), 0.25, axis=axis)
    return float(out) if np.ndim(out) == 0 else out


def worst(values, axis: int = -1):
    out = np.max(_values(values, axis), axis=axis)
    return float(out) if np.ndim(out) == 0 else out


def _mean(values, axis: int = -1):
    out = np.mean(_values(values, axis), axis=axis)
    return float(out) if np.ndim(out) == 0 else out


#: name -> statistic of the pooled episodes
METRICS: dict[str, Callable] = {"mean": _mean, "iqm": iqm, "cvar20": cvar, "worst": worst}


def _pooled(statistic: Callable, n: int | None = None) -> Callable:
    """A statistic of several samples: `statistic` of their concatenation (of the first `n`)."""
    def stat(*samples, axis=-1):
        return statistic(np.concatenate(samples[:n], axis=axis), axis=axis)
    return stat


def _usable(samples: Sequence[np.ndarray]) -> bool:
    return (all(s.size >= 3 for s in samples) and all(np.all(np.isfinite(s)) for s in samples)
            and np.ptp(np.concatenate(samples)) > 0)


def interval(samples_per_seed: Sequence[Sequence[float]], statistic: Callable = _mean) -> list[float]:
    """95 % interval of `statistic` over the pooled samples, plants resampled within each seed
    (one sample: the plain bootstrap). A degenerate sample (constant, < 3 values, non-finite)
    gives the point value twice."""
    from scipy import stats

    samples = [np.asarray(s, float) for s in samples_per_seed]
    if not _usable(samples):
        value = statistic(np.concatenate(samples)) if sum(s.size for s in samples) else math.nan
        return [float(value), float(value)]
    method = "percentile" if statistic is worst else "BCa"
    with warnings.catch_warnings():  # degenerate resamples: the point value below
        warnings.simplefilter("ignore")
        res = stats.bootstrap(tuple(samples), _pooled(statistic), method=method,
                              rng=np.random.default_rng(BOOTSTRAP_SEED), **BOOTSTRAP)
    lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        value = float(statistic(np.concatenate(samples)))
        return [value, value]
    return [lo, hi]


def _paired(statistic: Callable, samples: Sequence[np.ndarray], point: float) -> list[float]:
    from scipy import stats

    if not (_usable(samples) and all(s.size == samples[0].size for s in samples)):
        return [point, point]
    with warnings.catch_warnings():  # a constant statistic (e.g. the reference against itself): no BCa
        warnings.simplefilter("ignore")
        res = stats.bootstrap(tuple(samples), statistic, paired=True, vectorized=True, method="BCa",
                              rng=np.random.default_rng(BOOTSTRAP_SEED), **BOOTSTRAP)
    lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
    return [point, point] if not (np.isfinite(lo) and np.isfinite(hi)) else [lo, hi]


def paired_difference(costs_per_seed: Sequence[Sequence[float]], reference: Sequence[float]) -> dict:
    """Relative difference of the mean cost to a reference's on the same plants
    (mean over seeds and plants / reference mean - 1), its paired 95 % interval (plants resampled
    jointly), and the probability of improvement: the share of (seed, plant) episodes cheaper than
    the reference's episode on that plant (ties count half). The same for the CVaR-20 (the worst
    20 % of the pooled episodes against the reference's worst 20 % on the same plants):
    `cvar20_diff_rel` and `cvar20_ci`, the paired test of a worst-case improvement, narrower than
    comparing the two unpaired CVaR intervals."""
    a = [np.asarray(s, float) for s in costs_per_seed]
    b = np.asarray(reference, float)
    if any(s.shape != b.shape for s in a):
        raise ValueError("paired_difference: every seed's episodes must be on the same plants as the reference's")
    k = len(a)

    def ratio(*xs, axis=-1):
        return np.mean(np.stack(xs[:k]), axis=(0, axis if axis < 0 else axis + 1)) / np.mean(xs[k], axis=axis) - 1.0

    def cvar_ratio(*xs, axis=-1):
        return cvar(np.concatenate(xs[:k], axis=axis), axis=axis) / cvar(xs[k], axis=axis) - 1.0

    diff = float(np.mean(a) / np.mean(b) - 1.0)
    cvar_diff = float(cvar(np.concatenate(a)) / cvar(b) - 1.0)
    p_improvement = float(np.mean([(s < b) + 0.5 * (s == b) for s in a]))
    return {"cost_diff_rel": diff, "ci": _paired(ratio, a + [b], diff), "p_improvement": p_improvement,
            "cvar20_diff_rel": cvar_diff, "cvar20_ci": _paired(cvar_ratio, a + [b], cvar_diff)}


def normalized_score(costs_per_seed: Sequence[Sequence[float]], zero: Sequence[float],
                     one: Sequence[float]) -> dict:
    """(mean(zero) - mean(costs)) / (mean(zero) - mean(one)): 0 at the `zero` controller's mean
    cost, 1 at the `one` controller's, on the same plants, with its paired 95 % interval. Where
    `one` costs more than `zero` on average the scale runs the other way (a controller better than
    `zero` scores below 0); the result says so with `one_worse_than_zero`."""
    a = [np.asarray(s, float) for s in costs_per_seed]
    z, o = np.asarray(zero, float), np.asarray(one, float)
    k = len(a)

    def score(*xs, axis=-1):
        mean_a = np.mean(np.stack(xs[:k]), axis=(0, axis if axis < 0 else axis + 1))
        mz, mo = np.mean(xs[k], axis=axis), np.mean(xs[k + 1], axis=axis)
        return (mz - mean_a) / (mz - mo)

    mz, mo = float(np.mean(z)), float(np.mean(o))
    if mz == mo:
        return {"score": math.nan, "ci": [math.nan, math.nan], "one_worse_than_zero": False}
    point = float((mz - np.mean(a)) / (mz - mo))
    return {"score": point, "ci": _paired(score, a + [z, o], point), "one_worse_than_zero": mo > mz}
