"""One agent period's samples, summarised in one compiled pass over every environment.

After the plant kernel has written a period's samples (`MillVibCore.YS`, `AUXS`), the environments
need, per environment: the band-pass filtered piston velocity's mean square (the reward's vibration
term and the observed running RMS), the position error's mean square (the reward's tracking term and
the episode's tracking RMS), the envelope's extremes (max |x|, min and max pL: termination) and the
acceleration samples appended to the episode's record (its severity at the end). Done with numpy
and scipy that is a dozen array calls per step whose fixed cost, serial Python, was about a third of
a 64-environment valve step, the part that no plant thread can share. Here it is one loop.

The arithmetic is the libraries' own, operation for operation, so the numbers are the same to the
last bit as ``scipy.signal.sosfilt`` (second-order sections in transposed direct form II, the
sections' states carried from period to period) followed by ``numpy.mean`` (numpy's pairwise
summation); `tests/test_envs.py` checks both against the libraries.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from millvib_env.plant.model import A_ACC, A_QL, A_U, A_XV, IPL, IV, IX

__all__ = ["summarize_period", "record_actuator", "pairwise_sum", "sosfilt_into"]

#: numpy's unrolled block of its pairwise summation (numpy/_core/src/umath/loops_utils.h.src)
_PW_BLOCKSIZE = 128


@njit(cache=True)
def _block_sum(a, lo, n):
    """numpy's pairwise summation of a block of at most _PW_BLOCKSIZE numbers: eight running sums."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def sosfilt_into(sos, x, zi, out):
    """``out[:], zi[:] = scipy.signal.sosfilt(sos, x, zi=zi)`` for one signal, the same arithmetic in the same
    order (transposed direct form II, section after section, per sample), so the same bits."""
    for k in range(x.shape[0]):
        x_cur = x[k]
        for s in range(sos.shape[0]):
            x_new = sos[s, 0] * x_cur + zi[s, 0]
            zi[s, 0] = sos[s, 1] * x_cur - sos[s, 4] * x_new + zi[s, 1]
            zi[s, 1] = sos[s, 2] * x_cur - sos[s, 5] * x_new
            x_cur = x_new
        out[k] = x_cur


@njit(cache=True)
def pairwise_sum(a, n):
    """Sum of a[:n] in numpy's pairwise order (so the same bits as ``numpy.sum``): blocks of up to
    _PW_BLOCKSIZE summed by `_block_sum`, longer runs split in two halves (the first a multiple of 8)
    and the halves' sums added; the recursion is unrolled onto explicit stacks."""
    if n <= _PW_BLOCKSIZE:
        return _block_sum(a, 0, n)
    node_lo = np.empty(128, np.int64)
    node_n = np.empty(128, np.int64)
    node_done = np.zeros(128, np.bool_)
    sums = np.empty(128)
    top = 0
    n_sums = 0
    node_lo[0], node_n[0], node_done[0] = 0, n, False
    top = 1
    while top > 0:
        top -= 1
        lo, m, done = node_lo[top], node_n[top], node_done[top]
        if m <= _PW_BLOCKSIZE:
            sums[n_sums] = _block_sum(a, lo, m)
            n_sums += 1
        elif done:  # both halves summed: combine them, first + second
            n_sums -= 1
            sums[n_sums - 1] = sums[n_sums - 1] + sums[n_sums]
        else:
            m2 = m // 2
            m2 -= m2 % 8
            node_lo[top], node_n[top], node_done[top] = lo, m, True
            node_lo[top + 1], node_n[top + 1], node_done[top + 1] = lo + m2, m - m2, False
            node_lo[top + 2], node_n[top + 2], node_done[top + 2] = lo, m2, False
            top += 3
    return sums[0]


@njit(cache=True)
def summarize_period(YS, AUXS, xd_step, spp, sos, zi, acc_trace, n_trace, vib_ms, err_ms, x_abs_max,
                     pl_min, pl_max):
    """Summarise the period just integrated, for every environment b.

    YS[b, 1:], AUXS[b, 1:]: the period's samples; xd_step[b, j]: the set-point of its j-th control
    sub-interval (spp samples each); sos, zi[b]: the band-pass filter's sections and environment b's
    section states (updated). Appends the acceleration samples to acc_trace[b] at n_trace[b]
    (advanced) and writes vib_ms[b] (mean square of the band-passed velocity), err_ms[b] (mean square
    of xd - x), x_abs_max[b], pl_min[b], pl_max[b].
    """
    n_env = YS.shape[0]
    n_samp = YS.shape[1] - 1
    n_sec = sos.shape[0]
    sq_v = np.empty(n_samp)
    sq_e = np.empty(n_samp)
    for b in range(n_env):
        x_max = 0.0
        p_lo = np.inf
        p_hi = -np.inf
        k0 = n_trace[b]
        for k in range(n_samp):
            x_cur = YS[b, k + 1, IV]
            for s in range(n_sec):  # scipy.signal.sosfilt's transposed direct form II, in its order
                x_new = sos[s, 0] * x_cur + zi[b, s, 0]
                zi[b, s, 0] = sos[s, 1] * x_cur - sos[s, 4] * x_new + zi[b, s, 1]
                zi[b, s, 1] = sos[s, 2] * x_cur - sos[s, 5] * x_new
                x_cur = x_new
            sq_v[k] = x_cur * x_cur
            x = YS[b, k + 1, IX]
            e = xd_step[b, k // spp] - x
            sq_e[k] = e * e
            x_max = max(x_max, abs(x))
            p = YS[b, k + 1, IPL]
            p_lo = min(p_lo, p)
            p_hi = max(p_hi, p)
            acc_trace[b, k0 + k] = AUXS[b, k + 1, A_ACC]
        n_trace[b] = k0 + n_samp
        vib_ms[b] = pairwise_sum(sq_v, n_samp) / n_samp  # numpy.mean
        err_ms[b] = pairwise_sum(sq_e, n_samp) / n_samp
        x_abs_max[b] = x_max
        pl_min[b] = p_lo
        pl_max[b] = p_hi


@njit(cache=True)
def _max_abs(m, v):
    """max(m, |v|) as numpy's maximum takes it: a NaN on either side gives NaN."""
    a = abs(v)
    return a if (a > m or a != a) else m


@njit(cache=True)
def record_actuator(AUXS, n_valid, u_max, pl_lo, pl_hi, rec):
    """Add the period just integrated to each environment's actuator record rec[b] (`MillVibCore.actuator`):
    the command's largest magnitude (V) and its samples at the amplifier's limit u_max[b], the samples, the
    largest port opening and flow, the pressure's range (pl_lo, pl_hi from `summarize_period`). Only the
    samples the kernel wrote count: AUXS[b, k] for 1 <= k < n_valid[b]."""
    n_samp = AUXS.shape[1] - 1
    for b in range(AUXS.shape[0]):
        u_abs, xv_abs, ql_abs = 0.0, 0.0, 0.0
        n_lim = 0
        n_ok = 0
        for k in range(1, n_samp + 1):
            if k >= n_valid[b]:
                break
            u = abs(AUXS[b, k, A_U])
            u_abs = _max_abs(u_abs, u)
            if u >= u_max[b]:
                n_lim += 1
            n_ok += 1
            xv_abs = _max_abs(xv_abs, AUXS[b, k, A_XV])
            ql_abs = _max_abs(ql_abs, AUXS[b, k, A_QL])
        rec[b, 0] = _max_abs(rec[b, 0], u_abs)
        rec[b, 1] += n_lim
        rec[b, 2] += n_ok
        rec[b, 3] = _max_abs(rec[b, 3], xv_abs)
        rec[b, 4] = _max_abs(rec[b, 4], ql_abs)
        rec[b, 5] = min(rec[b, 5], pl_lo[b]) if pl_lo[b] == pl_lo[b] else pl_lo[b]
        rec[b, 6] = max(rec[b, 6], pl_hi[b]) if pl_hi[b] == pl_hi[b] else pl_hi[b]
