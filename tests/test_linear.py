"""Linearisation and the stability map, checked against simulation."""
import numpy as np
import pytest

from millvib_env import MillParams, PIDGains
from millvib_env.analysis.dynamics import classify_motion
from millvib_env.analysis.linear import critical_kp, jacobian, operating_point, stability_map
from millvib_env.plant.integrate import simulate


@pytest.mark.parametrize("c1, ct", [(2.25e6, 5e-16), (2.25e5, 5e-16), (1.25e5, 5e-9), (6e5, 5e-10)])
def test_local_critical_gain_separates_settling_from_sustained_vibration(c1, ct):
    # the linearisation is of the autonomous loop: switch the pump forcing off to test it
    params = MillParams(c1=c1, Ct=ct, pulse_amp=0.0)
    kp_crit = critical_kp(params, 1e-3, friction="stick")
    outcomes = {}
    for factor in (0.8, 1.2):
        gains = PIDGains(factor * kp_crit, 1e-3)
        y0 = operating_point(params, gains).y.copy()
        y0[0] += 1e-6  # a small disturbance: the bristles stay in pre-sliding
        outcomes[factor] = classify_motion(simulate(params, gains, 0.6, y0=y0))
    assert outcomes[0.8].settled
    assert not outcomes[1.2].settled


def test_large_disturbances_destabilise_below_the_local_limit():
    # between the sliding and the stick critical gains a 1 mm start grows into a limit cycle
    # although the resting equilibrium is locally stable (hard excitation)
    params = MillParams(pulse_amp=0.0)
    kp_slide = critical_kp(params, 1e-3, friction="sliding")
    kp_stick = critical_kp(params, 1e-3, friction="stick")
    assert kp_slide < kp_stick
    kp = 0.5 * (1.2 * kp_slide + kp_stick)
    assert not classify_motion(simulate(params, PIDGains(kp, 1e-3), 0.6)).settled


def test_critical_gain_rises_with_damping():
    crit = stability_map([1.25e5, 5e5, 2.25e6], [5e-16], friction="stick")[:, 0]
    assert np.all(np.diff(crit) > 0)


def test_operating_point_is_an_equilibrium_with_the_leakage_offset():
    params = MillParams(Ct=5e-9, pulse_amp=0.0)
    gains = PIDGains(1e5, 1e-3)
    op = operating_point(params, gains)
    assert op.x < -1e-4  # a leaking cylinder sags under proportional control
    run = simulate(params, gains, 0.3)
    # within the friction band: the bristles hold up to fs = 22 kN, i.e. ~10 um against the stand
    assert run.x[-1] == pytest.approx(op.x, abs=params.fs / params.k1)
    settled = operating_point(params, gains, integral="settled")
    assert settled.x == 0.0 and settled.y[4] > 0


def test_jacobian_shapes():
    params, gains = MillParams(), PIDGains(1e5, 1e-3)
    assert jacobian(params, gains, operating_point(params, gains)).shape == (3, 3)
    assert jacobian(params, gains, operating_point(params, gains, integral="settled")).shape == (4, 4)


def _reference_root(fun, center, lo, hi):
    """The operating point's root as it was found in Python: step out from `center` on a log scale until the
    sign changes, then scipy's brentq with the same tolerances."""
    from scipy import optimize

    f0 = fun(center)
    for step in np.logspace(-9, 0, 46) * (hi - lo):
        for cand in (center - step, center + step):
            if lo < cand < hi and np.sign(fun(cand)) != np.sign(f0):
                a, b = sorted((center, cand))
                return optimize.brentq(fun, a, b, xtol=1e-15, rtol=1e-13, maxiter=200)
    return None


@pytest.mark.parametrize("integral", ["frozen", "settled"])
@pytest.mark.parametrize("friction", ["stick", "sliding"])
def test_the_compiled_operating_point_is_scipys_brentq_on_the_same_residual(friction, integral):
    """The compiled search (bracket and Brent's method) against scipy's brentq on the same residual, called
    from Python: the roots agree within brentq's own tolerance (xtol + rtol |x|), on plants across the studied
    ranges, and a plant without an operating point is refused in both."""
    from millvib_env.analysis import linear
    from millvib_env.plant.model import IUI, IX, IZ, NY, drive_vector

    rng = np.random.default_rng(11)
    found = 0
    for _ in range(12):
        params = MillParams(c1=float(10 ** rng.uniform(5.0, 6.4)), Ct=float(10 ** rng.uniform(-16, -9)))
        gains = PIDGains(float(10 ** rng.uniform(4, 7)), 1e-3)
        xd = float(rng.choice([0.0, 1e-3]))
        p = linear._mean_pack(linear._ideal(params))
        c = drive_vector(gains, xd=xd)
        y = np.zeros(NY)
        y[IX], y[IZ] = xd, 0.0 if friction == "stick" else params.fs / params.sigma0
        which = IX if integral == "frozen" else IUI
        center, lo, hi = (xd, -params.L1, params.L - params.L1) if integral == "frozen" else (0.0, -1e6, 1e6)
        expected = _reference_root(lambda v: linear._flow_residual(v, which, y, p, c), center, lo, hi)
        if expected is None:
            with pytest.raises(RuntimeError, match="no operating point"):
                operating_point(params, gains, xd, friction=friction, integral=integral)
            continue
        found += 1
        root = operating_point(params, gains, xd, friction=friction, integral=integral).y[which]
        assert abs(root - expected) <= 1e-15 + 1e-13 * abs(expected), (params.c1, params.Ct, gains.kp)
    assert found >= 4


@pytest.mark.parametrize("friction", ["stick", "sliding"])
def test_the_critical_kp_search_evaluates_the_spectral_abscissa(friction):
    # the search makes what does not depend on KP once and linearises in one compiled call: the same numbers as
    # spectral_abscissa at each KP (an ideal valve and one with dynamics; a KP whose loop has no operating point
    # counts as unstable, 1.0)
    from millvib_env.analysis.linear import _abscissa_of_log_kp, spectral_abscissa

    for params in (MillParams(c1=2.25e5, Ct=5e-10), MillParams(valve_wn_hz=100.0)):
        g = _abscissa_of_log_kp(params, 1e-3, 0.0, 0.0, friction)
        for log_kp in np.linspace(3.0, 10.0, 9):
            try:
                want = spectral_abscissa(params, PIDGains(10.0**log_kp, 1e-3), friction=friction)
            except RuntimeError:
                want = 1.0
            assert g(log_kp) == want, (params, log_kp)
