"""Public simulation API: `simulate` (one plant) and `simulate_batch` (N plants), two methods.

* ``method="fast"``: the compiled adaptive Bogacki-Shampine 3(2) kernel (`kernel.py`), batched
  over plants with numba threads; no Python per time step.
* ``method="reference"``: LSODA at tight tolerances. By default ODEPACK's LSODA runs each set-point
  segment whole in compiled code (`scipy.integrate.odeint`), calling the compiled right-hand side;
  ``ivp_method`` names a `scipy.integrate.solve_ivp` method instead ("LSODA", the same solver driven
  a step at a time from Python, slower: docs/performance.md; "RK45", the paper's ode45; Radau, BDF, DOP853, RK23), or
  "RK45-compiled": scipy's RK45 step for step in compiled code (`rk45.py`, the solver study's method).

Both call the same right-hand side (`model.plant_rhs`), sample on the same grid
``t_k = k * dt_out`` and return the same `SimResult`. A run that leaves the physical envelope
(non-finite state, piston outside its stroke, |pL| above `p_max`) or cannot be integrated is
flagged ``diverged`` with the time it happened; its samples after that time are NaN, never
silently.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Sequence, Union

import numpy as np

from millvib_env._checks import as_float, choice, instance, real, reals, shown
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains
from millvib_env.plant import kernel, rk45
from millvib_env.plant.model import (AUX, AUX_NAMES, C_XD, IPL, IX, NAUX, NY, P_L, P_L1, STATE_NAMES, STATES,
                                     PlantChange, drive_vector, initial_state, pack, state_scale)
from millvib_env.severity import Quantity, iso_zone, vibration_severity

__all__ = ["SimResult", "BatchResult", "simulate", "simulate_batch", "DEFAULT_RTOL_FAST",
           "DEFAULT_RTOL_REFERENCE", "state_scale"]

XdSpec = Union[float, np.ndarray, Callable[[np.ndarray], np.ndarray]]

DEFAULT_RTOL_FAST = 1e-6
DEFAULT_RTOL_REFERENCE = 1e-9
DEFAULT_DT_OUT = 1e-4  # s: 10 kHz samples, Nyquist 5 kHz, well above the 1 kHz severity band
P_MAX_FACTOR = 10.0  # |pL| above 10 x the mean supply pressure is reported as divergence
MAX_STEPS_PER_SECOND = 2_000_000
_ODEINT_MXSTEP = 50_000  # LSODA's steps per output interval before it stops (then solve_ivp takes the segment)
# odeint: ODEPACK's LSODA, each segment whole; RK45-compiled: scipy's RK45 step for step in compiled code (`rk45`)
IVP_METHODS = ("odeint", "RK45-compiled", "LSODA", "RK45", "RK23", "DOP853", "Radau", "BDF")


@dataclass
class SimResult:
    """One simulated run, sampled at ``t`` (s). Arrays in SI units, one per state of the plant's
    layout (`model.STATES`: x (m), v (m/s), pL (Pa), z (m, LuGre bristle), uI (V, the analog PID's
    integral term), xs and vs (m, m/s: the spool of a valve with dynamics)) and per auxiliary output
    (`model.AUX`: a (m/s^2), u (V, valve command), xv (m, port opening), QL (m^3/s, valve flow), Ff
    (N, friction), ps (Pa, supply)), and xd (m, set-point). The auxiliary outputs (one `plant_rhs`
    evaluation per sample, about as much work as the integration itself) are computed on first
    access, so a run whose caller reads only the states costs only its integration.
    """

    t: np.ndarray
    states: np.ndarray  # (n_t, NY), `model.STATES` order
    xd: np.ndarray
    params: MillParams
    gains: PIDGains
    method: str
    diverged: bool = False
    t_diverged: float | None = None
    status: str = "ok"
    n_steps: int = 0  # integrator work: steps (fast) or right-hand-side evaluations (reference)
    info: dict = field(default_factory=dict)
    _aux_fn: Callable[[], np.ndarray] | None = field(default=None, repr=False)
    _aux: np.ndarray | None = field(default=None, repr=False)

    @property
    def aux(self) -> np.ndarray:
        """(n_t, NAUX): the auxiliary outputs at every sample, `model.AUX` order (computed once, on first
        access)."""
        if self._aux is None:
            if self._aux_fn is None:
                raise ValueError("this SimResult has no auxiliary outputs: it was built without the function "
                                 "that computes them (runs from simulate and simulate_batch have it)")
            self._aux = self._aux_fn()
        return self._aux

    def __getstate__(self) -> dict:
        """For pickling (a run that comes back from another process): the auxiliary outputs computed, in place
        of the function that computes them."""
        state = dict(self.__dict__)
        if state.get("_aux_fn") is not None:
            state["_aux"], state["_aux_fn"] = self.aux, None
        return state

    if TYPE_CHECKING:  # one column per state and auxiliary output, set below from the layout in plant.model
        def __getattr__(self, name: str) -> np.ndarray: ...

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def window(self, t_start: float = 0.0) -> slice:
        """The samples from `t_start` (s, in [0, the run's end)) on; ValueError outside."""
        t_end = (len(self.t) - 1) * self.dt
        if isinstance(t_start, bool) or not isinstance(t_start, (int, float, np.floating, np.integer)) \
                or not math.isfinite(as_float(t_start)) or not 0.0 <= t_start < t_end:
            raise ValueError(f"t_start = {shown(t_start)} s is invalid: a time in [0, {t_end:g}) s, the run's record")
        k0 = int(math.ceil(t_start / self.dt - 1e-9))
        return slice(k0, None)

    def severity(self, *, t_start: float = 0.0, quantity: Quantity = "acceleration",
                 band: tuple[float, float] | None = None) -> float:
        """Vibration severity (mm/s) of the piston from `t_start` on (see `vibration_severity`).

        Raises ValueError for a diverged run (its samples after divergence are NaN).
        """
        if self.diverged:
            raise ValueError(f"run diverged at t = {self.t_diverged:.6g} s ({self.status}); "
                             "a diverged run has no severity")
        names = ("acceleration", "velocity", "displacement")
        sig = {"acceleration": self.a, "velocity": self.v, "displacement": self.x}[choice("quantity", quantity, names)]
        return vibration_severity(sig[self.window(t_start)], 1.0 / self.dt, quantity=quantity, band=band)

    def iso_zone(self, **kw) -> str:
        return iso_zone(self.severity(**kw))

    def tracking_rms(self, t_start: float = 0.0) -> float:
        """RMS of the position error xd - x (m) from `t_start` on."""
        w = self.window(t_start)
        return float(np.sqrt(np.mean((self.xd[w] - self.x[w]) ** 2)))


def _column(array: str, j: int, doc: str) -> property:
    return property(lambda self: getattr(self, array)[:, j], doc=doc)


for _j, _sig in enumerate(STATES):
    setattr(SimResult, _sig.name, _column("states", _j, f"{_sig.meaning} ({_sig.unit})"))
for _j, _sig in enumerate(AUX):
    setattr(SimResult, _sig.name, _column("aux", _j, f"{_sig.meaning} ({_sig.unit})"))


@dataclass
class BatchResult:
    """N runs on one time grid: arrays of shape (N, n_t); ``result[i]`` gives a SimResult.

    ``states`` is (N, n_t, NY) in the order of `model.STATES`; ``aux`` (N, n_t, NAUX) in the order of
    `model.AUX`, computed from the states on first access. ``result.x`` etc. give one
    (N, n_t) array per quantity.
    """

    t: np.ndarray
    states: np.ndarray  # (N, n_t, NY)
    xd: np.ndarray  # (N, n_t)
    params: list[MillParams]
    gains: list[PIDGains]
    method: str
    diverged: np.ndarray
    t_diverged: np.ndarray
    status: list[str]
    n_steps: np.ndarray
    wall_s: float
    drive: np.ndarray  # (N, NC): the drive vector of every run (gains, pL_ref, plant change, ...)
    _aux: np.ndarray | None = field(default=None, repr=False)

    @property
    def aux(self) -> np.ndarray:
        if self._aux is None:
            self._aux = np.stack([kernel.aux_at(self.t, self.states[b], pack(self.params[b]), self.drive[b],
                                                self.xd[b]) for b in range(len(self))])
        return self._aux

    def __len__(self) -> int:
        return self.states.shape[0]

    def _aux_of(self, i: int) -> np.ndarray:
        if self._aux is not None:
            return self._aux[i]
        return kernel.aux_at(self.t, self.states[i], pack(self.params[i]), self.drive[i], self.xd[i])

    def __getitem__(self, i: int) -> SimResult:
        return SimResult(t=self.t, states=self.states[i], xd=self.xd[i], params=self.params[i], gains=self.gains[i],
                         method=self.method, diverged=bool(self.diverged[i]),
                         t_diverged=float(self.t_diverged[i]) if self.diverged[i] else None,
                         status=self.status[i], n_steps=int(self.n_steps[i]), _aux_fn=lambda: self._aux_of(i))

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __getattr__(self, name: str) -> np.ndarray:
        if name in STATE_NAMES:
            return self.states[:, :, STATE_NAMES.index(name)]
        if name in AUX_NAMES:
            return self.aux[:, :, AUX_NAMES.index(name)]
        raise AttributeError(name)


# --- argument handling ---------------------------------------------------------------------------
#: samples per run beyond which a run is refused before allocation (1e7 = 1000 s at 10 kHz; each run
#: keeps about a dozen float64 records of this length)
MAX_SAMPLES = 10_000_000


def _real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _check_stroke(p_list, xs) -> None:
    """Each start position within its cylinder's stroke (-L1, L - L1)."""
    for p, x in zip(p_list, xs):
        if not (-p.L1 < x < p.L - p.L1):
            raise ValueError(f"x0 = {float(x)!r} m is outside the stroke (-L1, L-L1) = ({-p.L1}, {p.L - p.L1})")


def _check_setpoint(p_list, XD: np.ndarray) -> None:
    """Each plant's set-point within its cylinder's stroke (-L1, L - L1): a gap the piston cannot reach is no
    set-point (a 1 m one ran to the envelope and reported a severity)."""
    for p, row in zip(p_list, XD):
        lo, hi = float(row.min()), float(row.max())
        if lo <= -p.L1 or hi >= p.L - p.L1:
            bad = lo if lo <= -p.L1 else hi
            raise ValueError(f"xd = {bad!r} m is outside the stroke (-L1, L-L1) = ({-p.L1}, {p.L - p.L1})")


def _time_grid(t_end: float, dt_out: float) -> np.ndarray:
    if not _real(t_end) or not _real(dt_out):
        raise ValueError(f"t_end = {shown(t_end)} s and dt_out = {shown(dt_out)} s must be numbers (s)")
    if not (math.isfinite(as_float(t_end)) and t_end > 0):
        raise ValueError(f"t_end = {shown(t_end)} s is invalid: must be finite and > 0")
    if not (math.isfinite(as_float(dt_out)) and 0 < dt_out <= t_end):
        raise ValueError(f"dt_out = {shown(dt_out)} s is invalid: must be in (0, t_end = {t_end}]")
    ratio = as_float(t_end) / as_float(dt_out)  # in float64: a float32 t_end / dt_out can overflow to inf
    n = int(round(ratio)) + 1 if ratio < MAX_SAMPLES else MAX_SAMPLES + 1
    if n > MAX_SAMPLES:
        raise ValueError(f"t_end = {shown(t_end)} s with dt_out = {shown(dt_out)} s would need {ratio + 1:.3g} "
                         f"samples per run; allowed up to {MAX_SAMPLES:.0e} (at most {MAX_SAMPLES * dt_out:.3g} s at "
                         "this dt_out)")
    return np.arange(n) * dt_out


def _as_floats(name: str, value) -> np.ndarray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} = {shown(value)} is invalid: a finite number or an array of them (m)") from None


def _xd_samples(xd: XdSpec, t: np.ndarray, n_plants: int) -> np.ndarray:
    if callable(xd):
        vals = _as_floats("xd(t)", xd(t))
        if vals.shape == ():
            vals = np.array([float(xd(tk)) for tk in t])
    else:
        vals = _as_floats("xd", xd)
    if vals.ndim == 0:
        vals = np.full(t.shape, float(vals))
    if vals.shape[-1] != t.size or vals.ndim > 2:
        raise ValueError(f"xd has shape {vals.shape}; expected a scalar, a function of t, ({t.size},) "
                         f"or ({n_plants}, {t.size}) samples on the output grid")
    if not np.all(np.isfinite(vals)):
        raise ValueError("xd contains NaN or inf")
    return np.ascontiguousarray(np.broadcast_to(vals, (n_plants, t.size)))


def _as_list(obj, cls, n: int | None, name: str) -> list:
    if isinstance(obj, cls):
        return [obj] * (n or 1)
    if isinstance(obj, (str, bytes, dict)) or not hasattr(obj, "__iter__"):
        raise ValueError(f"{name} = {shown(obj)} is invalid: a {cls.__name__} or a sequence of them")
    items = list(obj)
    if not items:
        raise ValueError(f"{name} is empty: give at least one {cls.__name__}")
    for item in items:
        if not isinstance(item, cls):
            raise ValueError(f"{name} must be {cls.__name__} or a sequence of them, got {type(item).__name__}")
    return items


def _plants_and_gains(params, gains) -> tuple[list, list]:
    """`simulate_batch`'s params and gains as two lists of equal length (a single object is shared by all)."""
    n = None
    for obj, cls, name in ((params, MillParams, "params"), (gains, PIDGains, "gains")):
        if not isinstance(obj, cls):
            if isinstance(obj, (str, bytes, dict)) or not hasattr(obj, "__len__"):
                raise ValueError(f"{name} = {shown(obj)} is invalid: a {cls.__name__} or a sequence of them")
            n = len(obj) if n is None else n
    p_list = _as_list(params, MillParams, n, "params")
    g_list = _as_list(gains, PIDGains, n, "gains")
    if len(p_list) != len(g_list):
        raise ValueError(f"params ({len(p_list)}) and gains ({len(g_list)}) must have the same length")
    return p_list, g_list


def _initial_states(y0, n: int) -> np.ndarray:
    """The N plants' full initial states: finite, one state (`model.STATES`) for all or one per plant."""
    allowed = f"{NY} finite numbers ({', '.join(STATE_NAMES)}), or one such row per plant ({n})"
    try:
        y = np.asarray(y0, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"y0 = {shown(y0)} is invalid: {allowed}") from None
    if y.shape not in ((NY,), (1, NY), (n, NY)) or not np.all(np.isfinite(y)):
        raise ValueError(f"y0 = {shown(y0)} is invalid: {allowed}")
    return np.ascontiguousarray(np.broadcast_to(y, (n, NY)))


def _start_positions(x0, n: int) -> np.ndarray:
    """The N plants' start positions (m): one finite number for all or one per plant."""
    x0a = _as_floats("x0", x0)
    if x0a.ndim > 1 or x0a.size not in (1, n):
        raise ValueError(f"x0 = {shown(x0)} is invalid: a number (m) or one per plant ({n})")
    x0s = np.broadcast_to(x0a.reshape(-1), (n,))
    if not np.all(np.isfinite(x0s)):
        raise ValueError(f"x0 = {shown(x0)} is invalid: must be finite")
    return x0s


def _check_rtol(rtol: float) -> float:
    return real("rtol", rtol, lo=1e-14, hi=1e-2)


# --- public API ---------------------------------------------------------------------------------
def simulate(params: MillParams | None = None, gains: PIDGains | None = None, t_end: float = 0.5, *,
             x0: float = 1.0e-3, xd: XdSpec = 0.0, method: str = "fast", dt_out: float = DEFAULT_DT_OUT,
             rtol: float | None = None, ivp_method: str = "odeint", u_ext: float = 0.0,
             pid_on: bool = True, y0: np.ndarray | None = None, change: PlantChange | None = None,
             ivp_options: dict | None = None) -> SimResult:
    """Simulate one closed-loop plant from the paper's initial state.

    Parameters
    ----------
    params, gains : plant and PID gains (default: Table 1 and the paper's KP=1e5, KI=1e-3, KD=0).
    t_end : simulated time (s); samples every `dt_out` s from 0 to t_end.
    x0 : initial displacement (m); the plant starts at rest with zero acceleration (docs/model.md).
    xd : set-point (m): a constant, a function of t, or samples on the output grid (held between
        samples; the integration restarts at every change).
    method : "fast" (compiled BS3(2)) or "reference" (LSODA; `ivp_method`).
    rtol : relative tolerance (default 1e-6 fast, 1e-9 reference); atol = rtol * state_scale.
    u_ext, pid_on : constant extra valve command (V) and whether the PID acts.
    y0 : full initial state (`model.STATES`: x, v, pL, z, uI, xs, vs), overriding x0.
    change : a change of c1 and Ct during the run (`PlantChange`), integrated by the same equations.
    ivp_method : reference method only: "odeint" (ODEPACK's LSODA, each segment in compiled code),
        "RK45-compiled" (scipy's RK45 step for step in compiled code, `plant.rk45`) or a `solve_ivp` method
        ("LSODA", "RK45" = MATLAB's ode45, "RK23", "DOP853", "Radau", "BDF").
    ivp_options : reference method only: ``atol`` (scalar or per state, replacing rtol * state
        scale) and ``max_step`` (s), e.g. MATLAB ode45's defaults ``{"atol": 1e-6}`` with
        ``rtol=1e-3``.

    With ``gains.kpl > 0`` the pressure feedback acts on pL - pL(0): the reference is the initial
    chamber pressure.
    """
    params = MillParams() if params is None else instance("params", params, MillParams, "a MillParams")
    gains = PAPER_GAINS if gains is None else instance("gains", gains, PIDGains, "a PIDGains")
    res = simulate_batch([params], [gains], t_end, x0=x0, xd=xd, method=method, dt_out=dt_out, rtol=rtol,
                         ivp_method=ivp_method, u_ext=u_ext, pid_on=pid_on,
                         y0=y0, change=change,
                         ivp_options=ivp_options)
    out = res[0]
    out.info["wall_s"] = res.wall_s
    return out


def simulate_batch(params: MillParams | Sequence[MillParams], gains: PIDGains | Sequence[PIDGains],
                   t_end: float = 0.5, *, x0: float | np.ndarray = 1.0e-3, xd: XdSpec = 0.0,
                   method: str = "fast", dt_out: float = DEFAULT_DT_OUT, rtol: float | None = None,
                   ivp_method: str = "odeint", u_ext: float = 0.0, pid_on: bool = True,
                   y0: np.ndarray | None = None, progress: bool = False,
                   change: PlantChange | Sequence[PlantChange | None] | None = None,
                   ivp_options: dict | None = None) -> BatchResult:
    """Simulate N independent plants, each with its own parameters and gains.

    `params` and `gains` are single objects (shared) or sequences of equal length N. The fast
    method advances all N plants in one compiled, multi-threaded call. Other arguments as in
    `simulate`; `x0` may be an array of N values and `xd` an (N, n_t) array.
    """
    t = _time_grid(t_end, dt_out)
    t_end, dt_out = float(t_end), float(dt_out)
    if not isinstance(pid_on, (bool, np.bool_)):
        raise ValueError(f"pid_on = {shown(pid_on)} is invalid: True or False")
    u_ext = real("u_ext", u_ext)  # V
    p_list, g_list = _plants_and_gains(params, gains)
    N = len(p_list)
    XD = _xd_samples(xd, t, N)
    _check_setpoint(p_list, XD)
    x0s = _start_positions(x0, N)
    P = np.stack([pack(p) for p in p_list])
    if y0 is None:
        _check_stroke(p_list, x0s)  # before the start's pressure balance divides by the chamber's length
        Y0 = np.stack([initial_state(p, x0=float(xx)) for p, xx in zip(p_list, x0s)])
    else:
        Y0 = _initial_states(y0, N)
    changes: list[PlantChange | None] = (list(change) if isinstance(change, (list, tuple))
                                         else [change] * N)  # type: ignore[list-item]
    if len(changes) != N:
        raise ValueError(f"change has {len(changes)} entries for {N} plants")
    for k, ch in enumerate(changes):
        if ch is not None and not isinstance(ch, PlantChange):
            raise ValueError(f"change{'' if change is ch else f'[{k}]'} = {shown(ch)} is invalid: None or a "
                             "PlantChange (or one per plant)")
    C = np.stack([drive_vector(g, u_ext=u_ext, pid_on=pid_on, pl_ref=float(y[IPL]), change=ch)
                  for g, y, ch in zip(g_list, Y0, changes)])
    _check_stroke(p_list, Y0[:, IX])
    p_max = P_MAX_FACTOR * max(p.ps for p in p_list)
    max_steps = int(MAX_STEPS_PER_SECOND * max(t_end, 1e-3)) + 1000

    start = time.perf_counter()
    if method == "fast":
        rtol = _check_rtol(DEFAULT_RTOL_FAST if rtol is None else rtol)
        atol = np.stack([rtol * state_scale(p) for p in p_list])
        YS = np.empty((N, t.size, NY))
        status = np.zeros(N, dtype=np.int64)
        t_fail = np.full(N, np.nan)
        n_steps = np.zeros(N, dtype=np.int64)
        kernel.simulate_batch_kernel(P, C, Y0, XD, float(dt_out), rtol, atol, p_max, max_steps,
                                     YS, status, t_fail, n_steps)
    elif method == "reference":
        rtol = _check_rtol(DEFAULT_RTOL_REFERENCE if rtol is None else rtol)
        choice("ivp_method", ivp_method, IVP_METHODS)
        options = dict(ivp_options or {})
        unknown = set(options) - {"atol", "max_step"}
        if unknown:
            raise ValueError(f"ivp_options: unknown key(s) {sorted(unknown, key=repr)}; allowed: atol, max_step")
        if "atol" in options:
            atol_given = options["atol"]
            options["atol"] = (real("ivp_options['atol']", atol_given, lo=0.0, lo_open=True)
                               if np.ndim(atol_given) == 0 else
                               np.array(reals("ivp_options['atol']", atol_given, lo=0.0, lo_open=True)))
            if np.ndim(options["atol"]) == 1 and len(options["atol"]) != NY:
                raise ValueError(f"ivp_options['atol'] has {len(options['atol'])} entries; allowed: one number or "
                                 f"one per state ({NY})")
        if "max_step" in options:
            options["max_step"] = real("ivp_options['max_step']", options["max_step"], lo=0.0, lo_open=True)
        YS, status, t_fail, n_steps = _reference_batch(P, C, Y0, XD, t, rtol, p_list, ivp_method,
                                                       p_max, progress, options)
    else:
        raise ValueError(f"method = {shown(method)} is invalid: use 'fast' or 'reference'")
    wall = time.perf_counter() - start
    return BatchResult(t=t, states=YS, xd=XD, params=p_list, gains=g_list, method=method,
                       diverged=status != kernel.OK, t_diverged=t_fail,
                       status=[kernel.STATUS_TEXT[int(s)] for s in status], n_steps=n_steps, wall_s=wall,
                       drive=C)


def _reference_batch(P, C, Y0, XD, t, rtol, p_list, ivp_method, p_max, progress, options):
    N = P.shape[0]
    YS = np.full((N, t.size, NY), np.nan)
    status = np.zeros(N, dtype=np.int64)
    t_fail = np.full(N, np.nan)
    n_steps = np.zeros(N, dtype=np.int64)
    iterator = range(N)
    if progress:
        from tqdm.auto import tqdm
        iterator = tqdm(iterator, desc="reference", unit="plant")
    for b in iterator:
        YS[b], status[b], t_fail[b], n_steps[b] = _reference_one(P[b], C[b], Y0[b], XD[b], t, rtol,
                                                                 p_list[b], ivp_method, p_max, options)
    return YS, status, t_fail, n_steps


class _LeftEnvelope(Exception):
    """Raised from odeint's right-hand side when a state it tries is outside the physical envelope."""


def _odeint_segment(p, c, y, ts, rtol, atol, lo, hi, p_max, options):
    """One set-point segment by ODEPACK's LSODA, run whole in compiled code (`scipy.integrate.odeint`),
    calling the compiled `plant_rhs`: the samples ``ts[1:]`` and the number of evaluations, or None where a
    state it tried left the envelope or LSODA stopped (the caller then runs the segment with solve_ivp's
    event location, which finds the time it left)."""
    from scipy.integrate import odeint

    dy, aux = np.empty(NY), np.empty(NAUX)  # odeint copies the derivative out before its next call

    def rhs(yy, tt):
        x = yy[IX]
        if not (lo < x < hi and abs(yy[IPL]) < p_max):  # False for NaN too
            raise _LeftEnvelope
        kernel.rhs_into(tt, yy, p, c, dy, aux)
        return dy

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a failed call is reported by istate and handled below
            ys, info = odeint(rhs, y, ts, rtol=rtol, atol=atol, full_output=True, mxstep=_ODEINT_MXSTEP,
                              hmax=float(options.get("max_step", 0.0)), tcrit=ts[-1:])
    except _LeftEnvelope:
        return None
    out = ys[1:]
    if info["message"] != "Integration successful." or not np.all(np.isfinite(out)):
        return None
    x = out[:, IX]
    if not (np.all((x > lo) & (x < hi)) and np.all(np.abs(out[:, IPL]) < p_max)):
        return None
    return out, int(info["nfe"][-1])


def _reference_one(p, c0, y0, xd, t, rtol, params, ivp_method, p_max, options):
    from scipy.integrate import solve_ivp  # here: over a second of imports that only the reference needs

    atol = options.get("atol", rtol * state_scale(params))
    extra = {"max_step": float(options["max_step"])} if "max_step" in options else {}
    atol_vector = np.ascontiguousarray(np.broadcast_to(np.asarray(atol, dtype=float), (NY,)))
    max_step = float(options.get("max_step", np.inf))
    lo, hi = -p[P_L1], p[P_L] - p[P_L1]

    def inside_envelope(_t, y, c):  # > 0 while inside: stroke margin and pressure margin
        return min(y[IX] - lo, hi - y[IX], (p_max - abs(y[IPL])) * 1e-9)

    inside_envelope.terminal = True

    def rhs(tt, y, c):
        return kernel.rhs_vector(tt, y, p, c)

    out = np.full((t.size, NY), np.nan)
    out[0] = y0
    y = y0.copy()
    n_evals = 0
    j0 = 0
    n = t.size
    while j0 < n - 1:
        j1 = j0 + 1
        while j1 < n - 1 and xd[j1] == xd[j0]:
            j1 += 1
        c = c0.copy()
        c[C_XD] = xd[j0]
        if ivp_method == "RK45-compiled":
            code, evals = rk45.rk45_segment(p, c, y, float(t[j0]), t[j0 + 1:j1 + 1], rtol, atol_vector,
                                            max_step, lo, hi, p_max, out[j0 + 1:j1 + 1])
            if code == rk45.DONE:
                n_evals += evals
                y = out[j1].copy()
                j0 = j1
                continue
        if ivp_method == "odeint":
            seg = _odeint_segment(p, c, y, t[j0:j1 + 1], rtol, atol, lo, hi, p_max, options)
            if seg is not None:
                out[j0 + 1:j1 + 1], evals = seg
                n_evals += evals
                y = out[j1].copy()
                j0 = j1
                continue
        # a solve_ivp method, or the segment in which the state leaves the envelope: the event finds when
        fallback = {"odeint": "LSODA", "RK45-compiled": "RK45"}
        sol = solve_ivp(rhs, (t[j0], t[j1]), y, method=fallback.get(ivp_method, ivp_method),
                        t_eval=t[j0 + 1:j1 + 1], rtol=rtol, atol=atol, args=(c,), events=inside_envelope, **extra)
        n_evals += sol.nfev
        m = sol.y.shape[1]
        out[j0 + 1:j0 + 1 + m] = sol.y.T
        if sol.status != 0 or m < j1 - j0 or not np.all(np.isfinite(sol.y)):
            t_bad = sol.t_events and [te[0] for te in sol.t_events if len(te)]
            tf = float(min(t_bad)) if t_bad else float(sol.t[-1] if sol.t.size else t[j0])
            out[j0 + 1 + m:] = np.nan
            return out, kernel.LEFT_ENVELOPE if sol.status >= 0 else kernel.STEP_UNDERFLOW, tf, n_evals
        y = sol.y[:, -1].copy()
        j0 = j1
    return out, kernel.OK, np.nan, n_evals
