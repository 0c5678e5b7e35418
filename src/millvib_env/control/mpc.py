"""Model-predictive control on the sampled loop: `mpc-oracle` and `mpc-preview`, the bound a controller of
any structure is measured against (not deployable: they read the plant's true state and parameters).

At every loop sample t_k (2 kHz on v1) the oracle commands the valve directly (the valve environment, no
PID under it) with the first move of

    min  sum_{j=1..N} q_x ((x_j - xd_j) / 10 um)^2 + q_v (v_j / 4.5 mm/s)^2 + q_i (xi_j / 1e-7 m s)^2
         + s_N' P s_N + r sum_{j=0..N-1} ((u_j - u0) / 10 V)^2 + r_d sum ((u_j - u_(j-1)) / 10 V)^2
    s.t. s_(j+1) = A s_j + B (u_j - u0) + E e_j,   -u_max <= u_j <= u_max,

a quadratic programme solved exactly by DAQP's dual active-set method (condensed and dense: the N commands are
the variables, the +-u_max box the only constraints). The model (A, B, E) is the plant's own linearisation
(`analysis.linear.linearize`, numerical derivatives of `plant_rhs`, sliding friction, B as the secant over
u0 +- `du_v`), with the spool's dynamics, sampled with a zero-order hold at the loop's period; xi is the
integral of the position error (integral action: the linear model's offsets are removed) and P the horizon's
tail (`MPCSettings.tail`): the stage weight once more, what every shipped bound was tuned and measured with. The
discrete Riccati solution of the same weights ("riccati") moved the bounds' mean cost by under 0.05 % on the main
plants of startup and rolling (and the CVaR-20 by under 0.3 %), both ways. Before, P was meant to be that solution
for every bound, but with no weight on xi (q_i 0, every shipped bound) scipy refused the equation on most plants
and the tail fell back to the stage weight, on others not, as rounding fell: the tail is now chosen, never fallen
into. The exogenous inputs e_j are the
rolling force's deviation (force steps, eccentricity), the supply pressure's ripple and the set-point.

The computation delay of the loop is respected: the command computed at t_k is applied from t_(k+1)
(``delay_samples = 1``), so the optimisation starts from the state predicted at t_(k+1) under the command
already held. The model is rebuilt when the plant (c1, Ct) moves by more than `REBUILD_LOG_STEP` (the
`change` task) or the set-point moves by more than `REBUILD_XD_M` (the `startup` ramp).

What each knows:

* `mpc-oracle`: the plant's parameters and its full state (no sensor noise) at every sample, and the
  disturbances' values now, held over the horizon;
* `mpc-preview`: the same, and the disturbances' and the set-point's true course over its preview (what an
  entry-thickness gauge upstream of the stand and the pass schedule would give, made exact, with the pump's
  ripple too): `preview_samples` ahead (the students' 20 ms), held from there to the end of a longer horizon.

The weights and the horizon are tuned per task on its tuning plants (configs/control/v1/<task>.yaml).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from millvib_env._checks import instance, real, shown
from millvib_env.analysis.linear import linearize
from millvib_env.control.base import Controller
from millvib_env.envs.batch import env_id_for
from millvib_env.loop.kernel import K_UAPP, K_UPEND
from millvib_env.params import MillParams
from millvib_env.plant.model import IUI, IX, STATE_NAMES, supply_ripple_rows
from millvib_env.threads import one_blas_thread

if TYPE_CHECKING:
    from millvib_env.envs.core import MillVibCore

__all__ = ["MPCSettings", "MPCModel", "MPCPolicy", "mpc_model", "offset_free_update", "REBUILD_LOG_STEP",
           "REBUILD_XD_M", "AHEAD", "FORCE_STEPS", "TAILS"]

#: the plant moves this far in log c1 or log Ct before the model is rebuilt (2 %)
REBUILD_LOG_STEP = 0.02
#: the set-point moves this far before the model is re-linearised (m)
REBUILD_XD_M = 2.0e-5
#: the exogenous courses a preview can know ahead (`MPCSettings.ahead`)
AHEAD = ("setpoint", "force_steps", "eccentricity", "ripple")
#: where the force steps ahead come from (`MPCSettings.force_steps`)
FORCE_STEPS = ("plant", "gauge")
#: the horizon's tail (`MPCSettings.tail`)
TAILS = ("stage", "riccati")
#: the cost's scales: position error, velocity (the benchmark's cost scales), integral, command
X_SCALE_M, V_SCALE_M_S, I_SCALE_M_S, U_SCALE_V = 1.0e-5, 4.5e-3, 1.0e-7, 10.0


@dataclass(frozen=True)
class MPCSettings:
    """The MPC's horizon (loop samples), weights (on the module docstring's scaled terms) and model."""

    horizon: int = 20
    q_x: float = 1.0
    q_v: float = 1.0
    q_i: float = 0.1
    r: float = 1e-3
    r_d: float = 0.0
    du_v: float = 1.0
    residual_filter: float = 0.2
    preview: bool = False
    #: with a preview, how far it reaches (loop samples; the course is held from there to the horizon's end); 0:
    #: the whole horizon
    preview_samples: int = 0
    #: with a preview, the courses it knows ahead (`AHEAD`); the others are held at their values now, as the
    #: oracle holds them (what each part of the bound's knowledge is worth: scripts/bound_knowledge.py)
    ahead: tuple = AHEAD
    #: with a preview, the force steps ahead as the plant applies them ("plant") or as the episode's measured
    #: preview predicts them ("gauge": `envs.gauge`, its timing, model and noise errors; the environment must
    #: measure its preview)
    force_steps: str = "plant"
    #: the horizon's tail P, added to the stage weight Q on the last state (`TAILS`): Q again ("stage": 2 Q on the
    #: last state), or the discrete Riccati solution of the same weights ("riccati": the infinite horizon's cost to
    #: go). The shipped bounds were tuned, and measured, with "stage" (the module docstring)
    tail: str = "stage"

    def __post_init__(self) -> None:
        if isinstance(self.horizon, bool) or not isinstance(self.horizon, (int, np.integer)) \
                or not 1 <= self.horizon <= 400:
            raise ValueError(f"MPCSettings.horizon = {shown(self.horizon)} is invalid: an integer in [1, 400] "
                             "(loop samples)")
        for name in ("q_x", "q_v", "q_i", "r", "r_d"):
            real(f"MPCSettings.{name}", getattr(self, name), lo=0.0, hi=1e12)
        real("MPCSettings.r", self.r, lo=0.0, lo_open=True, hi=1e12)
        real("MPCSettings.du_v", self.du_v, lo=0.0, lo_open=True, hi=100.0)
        real("MPCSettings.residual_filter", self.residual_filter, lo=0.0, hi=1.0)
        if not isinstance(self.preview, (bool, np.bool_)):
            raise ValueError(f"MPCSettings.preview = {shown(self.preview)} is invalid: True or False")
        if isinstance(self.preview_samples, bool) or not isinstance(self.preview_samples, (int, np.integer)) \
                or not 0 <= self.preview_samples <= 400:
            raise ValueError(f"MPCSettings.preview_samples = {shown(self.preview_samples)} is invalid: an integer in "
                             "[0, 400] (loop samples; 0: the whole horizon)")
        ahead = self.ahead
        if isinstance(ahead, str) or not isinstance(ahead, (tuple, list)) or len(set(ahead)) != len(ahead) \
                or any(a not in AHEAD for a in ahead):
            raise ValueError(f"MPCSettings.ahead = {shown(ahead)} is invalid: distinct names among {list(AHEAD)}")
        object.__setattr__(self, "ahead", tuple(ahead))
        if self.force_steps not in FORCE_STEPS:
            raise ValueError(f"MPCSettings.force_steps = {shown(self.force_steps)} is invalid: one of "
                             f"{list(FORCE_STEPS)}")
        if self.tail not in TAILS:
            raise ValueError(f"MPCSettings.tail = {shown(self.tail)} is invalid: one of {list(TAILS)}")


@dataclass
class MPCModel:
    """The condensed prediction for one plant and set-point (`mpc_model`)."""

    keep: list            # the plant states the model carries (indices into plant.model.STATES)
    y0: np.ndarray        # the operating point (all NY states)
    u0: float             # the command that holds it (V)
    xd0: float            # the set-point it was linearised at (m)
    Ad: np.ndarray        # (ns, ns): s = (y[keep] - y0[keep], xi)
    Bd: np.ndarray        # (ns,)
    Ed: np.ndarray        # (ns, 3): force (N), supply ripple (Pa), set-point deviation (m)
    H: np.ndarray         # (N, N) the QP's Hessian
    G_s: np.ndarray       # (N, ns) gradient per start state
    G_e: np.ndarray       # (N, 3 N) gradient per exogenous course
    G_u: np.ndarray       # (N,) gradient per held command (the move penalty's first term)
    G_w: np.ndarray       # (N, ns) gradient per model residual (held over the horizon)
    Q: np.ndarray         # (ns, ns) the stage weight and
    P: np.ndarray         # (ns, ns) the terminal one (the discrete Riccati solution)
    solver: Any = None  # a daqp.Model, set up on the scaled problem
    q_scale: float = 1.0


def offset_free_update(w: np.ndarray | None, miss: np.ndarray, a: float) -> np.ndarray:
    """The model's one-step residual, estimated: `miss` is what the last prediction, which already held the
    estimate `w`, missed; the estimate integrates it (gain `a` per sample). A steady model error r is then
    removed whole (w -> r, zero miss); a filter of the miss itself, w + a (miss - w), settles at r / 2."""
    return a * miss if w is None else w + a * miss


def _solve_first_move(solver: Any, q: np.ndarray) -> tuple[float, int]:
    """The box-constrained QP with the linear term `q` (a `daqp.Model` set up on the model's Hessian and the
    command's bounds), solved by DAQP's dual active-set method: its first move (nan where it failed) and DAQP's
    exit flag (1: optimal; negative: infeasible, cycling, iteration limit). DAQP solves a QP of this size in about
    12 us, a thirteenth of OSQP's warm-started solve that it replaced (the same first moves within 1e-7 V), and
    holds no signal handler of its own: a Ctrl-C is Python's as soon as the solve returns."""
    solver.update(f=q)
    x, _, flag, _ = solver.solve()
    flag = int(flag)
    return (float(x[0]) if flag >= 1 else math.nan), flag


def _zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy import linalg  # here: an environment (whose registry lists the MPC) need not import scipy

    n, m = A.shape[0], B.shape[1]
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = linalg.expm(M * dt)
    return E[:n, :n], E[:n, n:]


def _riccati_tail(Ad: np.ndarray, Bd: np.ndarray, Q: np.ndarray, R: float, n: int) -> np.ndarray:
    """`MPCSettings.tail` "riccati": the discrete Riccati solution P of the stage cost (Q, R) on the model (Ad, Bd),
    whose state is the plant's n states and the integral xi of the position error (the last). xi feeds nothing
    back: with no weight on it (q_i 0), the cost to go does not depend on it, so P is the plant states' own
    solution with a zero row and column for xi (solved on the whole model, that equation has xi's eigenvalue on
    the unit circle, and scipy refuses it on most plants and not on others, as rounding falls). A plant whose own
    equation has no stabilising solution is an error."""
    from scipy import linalg

    keep = n + 1 if Q[n, n] > 0.0 else n
    P = np.zeros_like(Q)
    try:
        P[:keep, :keep] = linalg.solve_discrete_are(Ad[:keep, :keep], Bd[:keep, None], Q[:keep, :keep],
                                                    np.array([[R]]))
    except (np.linalg.LinAlgError, ValueError) as err:
        raise ValueError(f"MPCSettings.tail = 'riccati': the plant's discrete Riccati equation has no stabilising "
                         f"solution ({err}); the weights q_x, q_v and r must be positive") from None
    return P


def mpc_model(params: MillParams, settings: MPCSettings, dt_s: float, xd: float = 0.0) -> MPCModel:
    """The condensed QP of `settings` for the plant `params` at set-point `xd`, sampled at `dt_s`. Built with BLAS
    on one thread (`one_blas_thread`): its products are a few hundred rows, and BLAS's threads, woken at every
    build (the startup ramp rebuilds a model every few samples), spun on the other cores and slowed the
    benchmark's worker processes (docs/performance.md)."""
    instance("params", params, MillParams, "a MillParams")
    instance("settings", settings, MPCSettings, "an MPCSettings")
    dt_s = real("dt_s", dt_s, lo=0.0, lo_open=True, hi=0.1)
    with one_blas_thread():
        return _build_model(params, settings, dt_s, xd)


@lru_cache(maxsize=8)
def _stacking(N: int, ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the condensed QP's stacking takes from its horizon N and state count ns alone, made once (the start
    ramp builds a model every few samples): the rows and columns of the target selector's ones (the tracking error
    x_j - xd_j = s_j[0] - (xd_j - xd0): the set-point deviation of e_j, applied over step j-1 -> j, is the one at
    t_j, so row (j - 1) ns of the stacked states takes column 3 (j - 1) + 2 of the exogenous inputs), and D, the
    command moves. Shared: read them, never write them."""
    rows, cols = np.arange(N) * ns, 3 * np.arange(N) + 2
    D = np.eye(N) - np.eye(N, k=-1)
    for a in (rows, cols, D):
        a.flags.writeable = False
    return rows, cols, D


def _toeplitz_blocks(M: np.ndarray) -> np.ndarray:
    """The block lower-triangular Toeplitz matrix of the blocks M[k] (N, ns, m): block (j, i) is M[j - i] for
    j >= i and M[0] * 0 above the diagonal (zeros of M[0]'s signs, the numbers the masked product that built it
    before gave), laid out (N, ns, N, m), a fresh array. Every block is a window of one padded array, so the only
    copy is the layout's."""
    N = M.shape[0]
    padded = np.concatenate([np.broadcast_to(M[0] * 0.0, (N - 1,) + M.shape[1:]), M])  # padded[N - 1 + d] = M[d]
    # window[j, :, :, w] = padded[j + w]; w = N - 1 - i gives padded[N - 1 + j - i]
    window = np.lib.stride_tricks.sliding_window_view(padded, N, axis=0)[..., ::-1]
    return window.transpose(0, 1, 3, 2).copy()


def _build_model(params: MillParams, settings: MPCSettings, dt_s: float, xd: float) -> MPCModel:
    ss = linearize(params, xd, friction="sliding", du=min(settings.du_v, params.u_max))
    keep = [STATE_NAMES.index(n) for n in ss.states]
    n = len(keep)
    ns = n + 1  # + the integral of the position error
    Ac = np.zeros((ns, ns))
    Ac[:n, :n] = ss.A
    Ac[n, 0] = -1.0  # d xi / dt = xd - x
    Bc = np.zeros((ns, 4))
    Bc[:n, 0] = ss.B[:, 0]
    Bc[:n, 1:3] = ss.E
    Bc[n, 3] = 1.0  # the set-point's deviation from xd0 feeds the integral
    Ad, BEd = _zoh(Ac, Bc, dt_s)
    Bd, Ed = BEd[:, 0], BEd[:, 1:]
    # the stage cost on s: weights of (x - xd), v, xi in scaled terms; the set-point enters through e
    iv = ss.states.index("v")
    Q = np.zeros((ns, ns))
    Q[0, 0] = settings.q_x / X_SCALE_M ** 2
    Q[iv, iv] = settings.q_v / V_SCALE_M_S ** 2
    Q[n, n] = settings.q_i / I_SCALE_M_S ** 2
    R = settings.r / U_SCALE_V ** 2
    P = _riccati_tail(Ad, Bd, Q, R, n) if settings.tail == "riccati" else Q.copy()
    N = int(settings.horizon)
    # stacked prediction: s_j = A^j s_0 + sum_i A^(j-1-i) (B u_i + E e_i), j = 1..N
    Apow = np.empty((N + 1, ns, ns))               # A^0 .. A^N
    Apow[0] = np.eye(ns)
    for k in range(N):
        np.matmul(Ad, Apow[k], out=Apow[k + 1])
    Phi = Apow[1:].reshape(N * ns, ns)
    # block (j, i) of the input maps is A^(j-1-i) B (Toeplitz in j - i): each power's product once, then placed
    Apow_a = Apow[:N]
    AB = Apow_a @ Bd                                # (N, ns): each power times Bd, as one product each
    AE = Apow_a @ Ed                                # (N, ns, 3)
    rows, cols, D = _stacking(N, ns)
    Gam = _toeplitz_blocks(AB[:, :, None]).reshape(N * ns, N)
    Gam_e = _toeplitz_blocks(AE).reshape(N * ns, 3 * N)
    # a residual w added at every step: s_j += sum_i A^(j-1-i) w, summed in the order of i for every j at once
    Gam_w3 = np.zeros((N, ns, ns))
    for i in range(N):
        Gam_w3[i:] += Apow_a[: N - i]
    Gam_w = Gam_w3.reshape(N * ns, ns)
    rd = settings.r_d / U_SCALE_V ** 2
    # the left factor of every product below, once: Gam' Qbar, Qbar block-diagonal (Q at every step, Q + P at the
    # last). Q is diagonal, so its blocks are Gam's rows scaled (the dense product's values: every other term is 0)
    GQ = Gam.T * np.tile(np.diag(Q), N)[None, :]
    GQ[:, -ns:] = Gam[-ns:, :].T @ (Q + P)
    H = GQ @ Gam + R * np.eye(N) + rd * D.T @ D
    H = 0.5 * (H + H.T)
    G_s = GQ @ Phi
    Gam_e[rows, cols] -= 1.0  # Gam_e - Tsel, the target selector Tsel's ones (every other entry less 0 is itself)
    G_e = GQ @ Gam_e
    G_u = np.zeros(N)
    G_u[0] = -rd  # the first move is from the command already held
    return MPCModel(keep=keep, y0=ss.op.y.copy(), u0=float(ss.op.y[IUI]), xd0=float(xd), Ad=Ad, Bd=Bd, Ed=Ed,
                    H=H, G_s=G_s, G_e=G_e, G_u=G_u, G_w=GQ @ Gam_w, Q=Q, P=P)


class MPCPolicy(Controller):
    """`mpc-oracle` / `mpc-preview` (module docstring): a valve-mode controller that reads the plant it
    runs on (`reads_plant`: the evaluation loop hands it the environment's core with `attach`)."""

    reads_plant = True
    batch_exact = True  # one QP per environment

    def __init__(self, name: str, settings: MPCSettings, version: str = "v1"):

        if version == "v0":
            raise ValueError(f"{name} runs on the loop as commissioned (environment version v1): the v0 analog "
                             "loop has no sampled controller to stand in for")
        self.name, self.settings = name, instance("settings", settings, MPCSettings, "an MPCSettings")
        self.env_id = env_id_for("valve", version)
        self.env_kwargs: dict = {}
        self.core: MillVibCore | None = None
        self._models: list[MPCModel | None] = []
        self._keys: list[tuple[float, float, float] | None] = []
        self._stack: dict[str, Any] = {}
        self._xi = np.zeros(0)
        self._steps: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}  # per horizon: the steps and midpoints
        #: QP solves that did not report 'solved' (their clipped first move is used)
        self.unsolved = 0
        self.solves = 0

    def attach(self, core, as_teacher: bool = False) -> None:
        """The environments' core (`envs.core.MillVibCore`) whose plants this oracle reads. As a controller it
        drives the valve alone; `as_teacher` attaches it to any valve environment of the sampled loop (a
        residual one too) to give `teacher_commands` for whatever drives it (`training.distill`)."""
        if core.settings.loop is None or core.settings.mode != "valve" or (core.settings.residual and not as_teacher):
            raise ValueError(f"{self.name} commands the valve of the sampled loop: run it in {self.env_id}")
        self.core = core
        n = core.settings.n
        self._models = [None] * n
        self._keys = [None] * n
        # per environment: a model is built, its set-point, and whether its plant moves within the episode
        self._built, self._built_xd, self._moves = np.zeros(n, bool), np.zeros(n), np.zeros(n, bool)
        self._stack = {}  # every environment's model, stacked (`_place`), made at the first model
        self._xi = np.zeros(n)

    @property
    def _core(self) -> MillVibCore:
        """The attached core (`attach`); a clear error before it is."""
        if self.core is None:
            raise ValueError(f"{self.name} reads the plant's state: run it in env = ctrl.make_env() or through "
                             "the benchmark's evaluation loop, which hand it the environments (attach)")
        return self.core

    def on_reset(self, infos, indices) -> None:
        st = self._stack
        for i in indices:
            self._xi[i] = 0.0
            if st:
                st["has_w"][i] = st["has_pred"][i] = False
                st["w"][i] = 0.0
            self._keys[i] = None  # a new episode, a new plant: the model is rebuilt at its first sample
            self._built[i] = False

    def _model(self, i: int, xd: float) -> MPCModel:
        core = self._core
        base = core.params[i]
        now = core.current_params(i)
        key = (math.log(now["c1"]), math.log(now["Ct"]), xd)
        old = self._keys[i]
        if old is not None and abs(old[0] - key[0]) <= REBUILD_LOG_STEP and abs(old[1] - key[1]) <= REBUILD_LOG_STEP \
                and abs(old[2] - xd) <= REBUILD_XD_M:
            model = self._models[i]
            assert model is not None  # a key is stored with its model
            return model
        import daqp

        loop = core.settings.loop
        assert loop is not None  # attach checks it
        m = mpc_model(base.replace(c1=now["c1"], Ct=now["Ct"]), self.settings, loop.dt_s, xd)
        N = m.H.shape[0]
        # solved in commands of U_SCALE_V and a cost of O(1): the weights' 1e10 spread stays out of the solver
        m.q_scale = U_SCALE_V / float(np.max(np.diag(m.H)) * U_SCALE_V ** 2)
        umax = base.u_max
        solver = daqp.Model()  # a dense dual active-set solver: the bounds on the N commands are its only constraints
        solver.setup(np.ascontiguousarray(m.H * U_SCALE_V * m.q_scale), np.zeros(N), np.zeros((0, N)),
                     np.full(N, (umax - m.u0) / U_SCALE_V), np.full(N, (-umax - m.u0) / U_SCALE_V))
        m.solver = solver
        self._models[i], self._keys[i] = m, key
        self._built[i], self._built_xd[i], self._moves[i] = True, xd, core.plant_moves(i)
        self._place(i, m, umax)
        return m

    def _place(self, i: int, m: MPCModel, umax: float) -> None:
        """Environment i's model into slot i of the stacked arrays that a sample's products run on for every
        environment at once (`teacher_commands`); the stack is made at the first model (its horizon and states
        are the settings' and the loop's, the same for every environment of a batch)."""
        st = self._stack
        N, ns = m.H.shape[0], len(m.keep) + 1
        if not st:
            n = self._core.settings.n
            st.update(keep=list(m.keep), Ad=np.zeros((n, ns, ns)), Bd=np.zeros((n, ns)), Ed=np.zeros((n, ns, 3)),
                      G_s=np.zeros((n, N, ns)), G_e=np.zeros((n, N, 3 * N)), G_u=np.zeros((n, N)),
                      G_w=np.zeros((n, N, ns)), y0=np.zeros((n, ns - 1)), u0=np.zeros(n), xd0=np.zeros(n),
                      q_scale=np.ones(n), umax=np.zeros(n), w=np.zeros((n, ns)), has_w=np.zeros(n, bool),
                      pred=np.zeros((n, ns - 1)), has_pred=np.zeros(n, bool))
        elif st["keep"] != list(m.keep) or st["G_s"].shape[1:] != (N, ns):
            raise ValueError(f"{self.name}: environment {i}'s plant keeps the states {list(m.keep)} where the "
                             f"others keep {st['keep']}: one batch runs plants of one valve model (ideal or not)")
        for k in ("Ad", "Bd", "Ed", "G_s", "G_e", "G_u", "G_w"):
            st[k][i] = getattr(m, k)
        st["y0"][i] = m.y0[m.keep]
        st["u0"][i], st["xd0"][i], st["q_scale"][i], st["umax"][i] = m.u0, m.xd0, m.q_scale, umax

    def _exogenous(self, idx: np.ndarray, xd0: np.ndarray, N: int) -> np.ndarray:
        """e_j of environments `idx` for the steps from t_k (j = 0: the step already committed) to t_(k+N):
        (len(idx), N + 1, 3). Without a preview, or for a course not in `settings.ahead`, the value now is held."""

        core = self._core
        assert core.settings.loop is not None  # attach checks it
        dt = core.settings.loop.dt_s
        k = core.control_sample(idx)
        t = core.time_now(idx)
        last = core.course_samples - 1
        at_now = at = np.repeat(np.minimum(k, last)[:, None], N + 1, axis=1)
        tm_now = tm = np.repeat(t[:, None], N + 1, axis=1)
        known = self.settings.ahead if self.settings.preview else ()
        if known:
            steps = self._steps.get(N)
            if steps is None or steps[2] != dt:
                ahead = np.arange(N + 1)
                if self.settings.preview_samples:  # the course known so far, held beyond
                    ahead = np.minimum(ahead, self.settings.preview_samples)
                steps = self._steps[N] = (ahead, (ahead + 0.5) * dt, dt)
            at = np.minimum(k[:, None] + steps[0], last)
            tm = t[:, None] + steps[1]  # the sinusoids at each hold's midpoint
        rows = idx[:, None]
        e = np.empty((len(idx), N + 1, 3))
        # the force steps and the eccentricity
        at_f, tm_f = (at if "force_steps" in known else at_now), (tm if "eccentricity" in known else tm_now)
        if self.settings.force_steps == "gauge" and known:
            e[:, :, 0] = core.gauge_force_course(rows, at_f, tm_f)
        else:
            e[:, :, 0] = core.force_course(rows, at_f, tm_f)
        tm_r = tm if "ripple" in known else tm_now
        e[:, :, 1] = supply_ripple_rows(np.ascontiguousarray(tm_r), core.plant_packs(idx))
        # the set-point at each step's end
        at_s = at if "setpoint" in known else at_now
        e[:, :, 2] = core.setpoint_course(rows, np.minimum(at_s + 1, last)) - xd0[:, None]
        return e

    def teacher_commands(self, idx: np.ndarray | None = None) -> np.ndarray:
        """The commands (V) the oracle sends (as a controller) or would send (as a teacher) from the state now of
        environments `idx` (default: all); their internal states move on: call it once per sample.

        Each environment's QP is its own (its plant's model, its DAQP solver); its linear term and the model's
        predictions are computed for every environment at once on the stacked models (`_place`): numpy's
        stacked matmul calls BLAS's gemv per environment as one environment's product does, and the other terms
        are the same elementwise operations in the same order, so every command is the one environment's own
        (to the bit in the four tasks' benchmarks, measured; tests/test_mpc.py compares them)."""

        core = self._core
        assert core.settings.loop is not None  # attach checks it
        idx = np.arange(core.settings.n) if idx is None else np.asarray(idx, dtype=np.intp)
        last = core.course_samples - 1
        xd_now = core.setpoint_course(idx, np.minimum(core.control_sample(idx), last))
        # `_model`'s test for each environment at once where its plant is fixed (its c1 and Ct, and their logs,
        # are the model's): a new model only where none is built or the set-point moved past REBUILD_XD_M
        check = ~self._built[idx] | self._moves[idx] | (np.abs(self._built_xd[idx] - xd_now) > REBUILD_XD_M)
        for i, x in zip(idx[check].tolist(), xd_now[check].tolist()):
            self._model(i, x)
        solvers = [self._models[i].solver for i in idx]  # type: ignore[union-attr]  # each built above
        st = self._stack
        whole = len(idx) == core.settings.n and bool(np.all(idx == np.arange(core.settings.n)))
        sel = slice(None) if whole else idx

        def mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:  # each slot's matrix times its vector
            return np.matmul(A, x[:, :, None])[:, :, 0]

        Ad, Bd, Ed, u0 = st["Ad"][sel], st["Bd"][sel], st["Ed"][sel], st["u0"][sel]
        N = st["G_s"].shape[1]
        y_now = core.plant_state(idx)
        y_kept = y_now[:, st["keep"]]
        y0 = st["y0"][sel]
        s = np.empty((len(idx), len(st["keep"]) + 1))
        s[:, :-1] = y_kept - y0
        s[:, -1] = self._xi[idx]
        e = self._exogenous(idx, st["xd0"][sel], N)
        # offset-free: what the model missed over the last sample (the valve's two gains, friction, the
        # operating point's drift), filtered and held over the horizon
        a = self.settings.residual_filter
        w, has_w = st["w"][idx], st["has_w"][idx]
        if a > 0.0:
            upd = st["has_pred"][idx]
            miss = np.zeros_like(s)
            miss[:, :-1] = y_kept - st["pred"][idx]
            # `offset_free_update` for every environment that has a prediction: a first estimate, or the last moved
            first, moved = offset_free_update(None, miss, a), offset_free_update(w, miss, a)
            w = np.where(upd[:, None], np.where(has_w[:, None], moved, first), w)
            has_w = has_w | upd
            st["w"][idx], st["has_w"][idx] = w, has_w
        w = np.where(has_w[:, None], w, 0.0)
        delayed = core.settings.loop.delay_samples > 0
        if delayed:  # the command held over [t_k, t_(k+1)] was computed a sample ago
            held = core.controller_state(idx, K_UPEND)
            s = mv(Ad, s) + Bd * (held - u0)[:, None] + mv(Ed, e[:, 0]) + w
            e_h = e[:, 1:]
        else:
            held = core.controller_state(idx, K_UAPP)
            e_h = e[:, :-1]
        q = mv(st["G_s"][sel], s) + mv(st["G_e"][sel], e_h.reshape(len(idx), -1)) \
            + st["G_u"][sel] * (held - u0)[:, None] + mv(st["G_w"][sel], w)
        q *= st["q_scale"][sel][:, None]
        z0 = np.empty(len(idx))
        for j, solver in enumerate(solvers):
            z0[j], status = _solve_first_move(solver, q[j])
            if status < 1:  # DAQP failed (its first move is then taken as no move from the operating point's command)
                self.unsolved += 1
        self.solves += len(idx)
        du = np.where(np.isfinite(z0), U_SCALE_V * z0, 0.0)
        umax = st["umax"][sel]
        u = np.minimum(np.maximum(u0 + du, -umax), umax)
        # the integral of the position error, as the model counts it (true position, no noise)
        self._xi[idx] += core.settings.loop.dt_s * (xd_now - y_now[:, IX])
        # the model's prediction of the next sample's plant state, absolute (a rebuilt model keeps it)
        nxt = s if delayed else mv(Ad, s) + Bd * (u - u0)[:, None] + mv(Ed, e[:, 0]) + w
        st["pred"][idx] = nxt[:, :-1] + y0
        st["has_pred"][idx] = True
        return u

    def teacher_command(self, i: int) -> float:
        """`teacher_commands` of environment i alone."""
        return float(self.teacher_commands(np.array([i]))[0])

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        core = self._core
        obs = np.asarray(observation)
        n = 1 if obs.ndim == 1 else obs.shape[0]
        u = self.teacher_commands(None if n == core.settings.n else np.arange(n))
        action = (u / core.settings.u_range).astype(np.float32)[:, None]
        return (action[0] if obs.ndim == 1 else action), state
