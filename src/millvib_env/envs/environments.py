"""The two Gymnasium environments. Both are thin wrappers over `MillVibCore` with one plant."""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym

from millvib_env._checks import seed_or_none, shown
from millvib_env.envs.actions import LoopController
from millvib_env.envs.build import build_core
from millvib_env.envs.config import EnvConfig
from millvib_env.envs.disturbances import Disturbance
from millvib_env.envs.envelope import EnvelopeFunction
from millvib_env.envs.reward import RewardFunction
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["MillVibEnv", "GainScheduleEnv", "ValveEnv"]


class MillVibEnv(gym.Env):
    """Common base: a new screw-down plant every episode (see the subclasses' manuals)."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}
    mode = "gain"

    def __init__(self, config: str | dict | EnvConfig | None = "startup", *, residual: bool = False,
                 observe_params: bool | None = None, observe_phase: bool | None = None,
                 render_mode: str | None = None, env_version: str = DEFAULT_VERSION,
                 extra_disturbances: Sequence[Disturbance] | None = None, reward_fn: RewardFunction | None = None,
                 envelope_fn: EnvelopeFunction | None = None, base_controller: LoopController | None = None,
                 **overrides: Any):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode = {shown(render_mode)} is invalid: one of {self.metadata['render_modes']} "
                             "or None")
        self.core = build_core(1, self.mode, env_version, config, residual=residual, observe_params=observe_params,
                               observe_phase=observe_phase, extra_disturbances=extra_disturbances,
                               reward_fn=reward_fn, envelope_fn=envelope_fn, base_controller=base_controller,
                               overrides=overrides)
        self.config = self.core.settings.cfg
        self.action_space = self.core.action_space
        self.observation_space = self.core.observation_space
        self.render_mode = render_mode
        self.core.keep_history = render_mode is not None  # the render's recent samples: kept only where drawn
        self._figure = None
        self._episode_over = True  # until the first reset

    @property
    def params(self):
        """The current episode's MillParams."""
        return self.core.params[0]

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed_or_none("seed", seed))
        self.core.np_random[0] = self.np_random
        obs, info = self.core.reset_env(0, None, options)
        self._episode_over = False
        if self.render_mode == "human":
            self.render()
        return obs, info

    def step(self, action):
        if self._episode_over:
            raise ValueError("step() called on an episode that has ended or never started: call reset() first")
        obs, reward, terminated, truncated, infos = self.core.step(action)
        self._episode_over = bool(terminated[0] or truncated[0])
        if self.render_mode == "human":
            self.render()
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), infos[0]

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'.")
            return None
        from millvib_env.envs.rendering import render_frame

        frame, self._figure = render_frame(self.core, self._figure, human=self.render_mode == "human",
                                           fps=self.metadata["render_fps"])
        return frame if self.render_mode == "rgb_array" else None

    def close(self):
        if self._figure is not None:
            import matplotlib.pyplot as plt

            plt.close(self._figure)
            self._figure = None


class GainScheduleEnv(MillVibEnv):
    """## Description

    A gain scheduler for the hydraulic screw-down (gap-control) cylinder of a rolling mill. The
    plant is the one of the source paper (servo valve and amplifier, cylinder with oil
    compressibility and internal leakage, LuGre seal friction, mill stand spring and damping,
    rolling force, 115.5 Hz pump pressure pulsation) under a continuous-time PID position loop.
    Every decision period (10 ms) the agent sets the PID gains. Each episode draws a new plant:
    the damping c1 and the internal leakage Ct, which drift with oil temperature and seal wear
    and make a fixed-gain PID fail, are log-uniform over [1.25e5, 2.25e6] N s/m and
    [5e-16, 5e-9] m^3/(s Pa). The agent does not see them; it must infer them from the response.

    ## Action Space

    ``Box(-1, 1, (3,), float32)``: (KP, KI, KD), each mapped on a log scale onto its bounds,
    ``g = 10 ** (log10(lo) + (a + 1) / 2 * (log10(hi) - log10(lo)))`` (`envs.actions.GainMap`, the one
    mapping). With ``actions={"pressure_feedback": True}`` an entry sets KPL (V/Pa, [1e-9, 1e-4]): the
    control law gains the pressure feedback ``- KPL (pL - pL_ref)``, the textbook active damping; with
    ``"force_feedforward": True`` an entry sets KFF (V/N, [1e-6, 1e-1]): ``+ KFF (FL(t) - FL)``, the
    load cells' force deviation fed forward. ``actions={"scale": "linear"}`` maps the bounds linearly.

    **Relative action** (``actions={"relative": {"base": [KP, KI, KD, KPL], "decades": [1, 1, 0, 1]}}``):
    each entry is a log offset of +-``decades`` around a base gain set, ``g = base * 10 ** (decades *
    a)``, so the zero action is exactly the base controller (e.g. ``pid-pf-robust``; `millvib train`
    resolves a base named in a hyperparameter file) and a gain with ``decades = 0`` stays pinned.

    | index | gain | unit | bounds (default config) |
    |---|---|---|---|
    | 0 | KP | V/m | [1e4, 1e7] (the paper's 1e5 and 3.5e6 inside; the stability limit, 5e5-1.4e7, reached) |
    | 1 | KI | V/(m s) | [1e-3, 1e8] |
    | 2 | KD | V s/m | [1, 300] (1 is negligible: derivative effectively off; 300 keeps 0.5 um of position-sensor noise, differentiated over 1 kHz, near 1 V RMS on the valve: the PID sees an ideal velocity, and a tuning with KD up to 3e4 found every plant damped by an ideal derivative alone, which no mill loop can do) |

    The PID runs continuously inside the simulation (u = KP e + uI - KD v, derivative on the
    measurement). Its state holds the integral *term* uI, so a gain change is bumpless: the
    integral term does not jump. Finite actions outside [-1, 1] are clipped; NaN, inf or a wrong
    shape raise ValueError.

    ## Observation Space

    ``Box(-1, 1, (8,), float32)`` by default. Signed-log channels are
    ``sign(q) ln(1 + |q|/q0) / ln(1 + q_max/q0)``:

    | index | observation | unit | scaling |
    |---|---|---|---|
    | 0 | position error xd - x | m | signed log, q0 = 1e-6, q_max = 5e-3 |
    | 1 | piston velocity | m/s | signed log, q0 = 1e-4, q_max = 5 |
    | 2 | piston acceleration (accelerometer) | m/s^2 | signed log, q0 = 1e-2, q_max = 1e5 |
    | 3 | chamber pressure pL | Pa | (pL - ps/2) / ps, clipped |
    | 4 | running RMS of band-limited (10-1000 Hz) velocity, time constant 20 ms | mm/s | log, q0 = 1e-2, q_max = 1e4 |
    | 5-7 | current KP, KI, KD (= the last action) | | the action's log mapping |
    | +2 | sin, cos of the pump phase (``observe_phase=True``) | | |
    | +2 | true log c1, log Ct over their ranges (``observe_params=True``, ablations only) | | linear to [-1, 1] |
    | +1 | load cells' rolling-force deviation FL(t) - FL (``observation={"force": True}``) | N | signed log, q0 = 1e3, q_max = 1e6 |

    Values are sampled at the end of each decision period; optional sensor noise and delay act on
    channels 0-2 (and the whole vector for the delay).

    ## Rewards

    Per step, with v_b the band-limited (10-1000 Hz, causal 4th-order Butterworth) velocity and
    e = xd - x sampled at 10 kHz over the period:
    ``r = -(w_v RMS(v_b) / 4.5 mm/s + w_e RMS(e) / 10 um + w_u mean|a_t - a_(t-1)| + w_o mean(a_t^2)) - P [terminated]``
    with w_v = w_e = 1, w_u = 0.05, w_o = 0, P = 100 (all in the config's ``reward`` section; w_o, the
    offset penalty, is a relative action's distance from its base controller). 4.5 mm/s is the
    ISO 20816-3 B/C boundary. The benchmark's episode cost is
    ``severity / 4.5 + tracking_rms / 10 um``; minus the mean per-step reward is the same sum with
    per-step RMS values, so it equals the cost for a steady response and is at most the cost
    (RMS of means <= overall RMS) when the response changes over the episode.

    ## Starting State

    Task ``startup`` (the default) in v0: the paper's: the piston 1 mm from the set-point
    (``initial.x0_m``, optionally jittered), at rest with zero acceleration (which fixes the chamber
    pressure), bristles at the static friction fs, zero integral. In v1: settled 0.3 mm out, the set-point
    then led back to 0 at 2 mm/s (``initial.setpoint_ramp_m_s``). Tasks ``rolling`` and ``change``
    (``initial.settled: true``): settled at the set-point, the integral term already holding the
    load and feeding the leak (in v1 the digital controller's integral term, and the valve's spool at the
    opening that feeds the leak). The PID starts with the paper's gains (KP = 1e5, KI = 1e-3, KD = 0), or
    with a relative action's base gains.

    ## Episode End

    * Termination: the plant leaves its physical envelope (|x| > 5 mm, pL < -1 MPa or pL > 3 ps,
      the piston outside its stroke, or a numerical failure), with the terminal penalty.
    * Truncation: after ``episode_s`` (0.5 s = 50 steps in ``startup``, 1 s = 100 steps in
      ``rolling`` and ``change``). The environment truncates by itself; no ``TimeLimit`` is
      registered, since the length depends on the config.

    At the end ``info`` carries the episode metrics: ``severity`` (mm/s, `vibration_severity` of the
    episode's acceleration), ``severity_start`` and ``severity_rest`` (its first 0.1 s and the rest),
    ``pump_line_mm_s`` and ``low_band_mm_s`` (the pump line's and the 10-100 Hz band's levels),
    ``tracking_rms_um``, ``iso_zone``, ``diverged``, ``episode_return``; and always ``params`` (the
    true c1, Ct, ... now: they move during a ``change`` episode). Stepping an episode that has ended,
    or was never reset, raises ValueError.

    ## Arguments

    ```python
    import gymnasium as gym
    import millvib_env
    env = gym.make("MillVib-GainSchedule-v0", config="default", observe_params=False,
                   observe_phase=False, render_mode=None, episode_s=0.5)
    obs, info = env.reset(seed=0, options={"params": {"c1": 1.25e5}})   # pin parameters
    obs, info = env.reset(options={"scenario": "low-damping"})         # a named failure case
    ```

    ``config`` names a YAML in configs/env/: a task's episode (``startup``, alias ``default``;
    ``rolling``: steady rolling under eccentricity, force steps, gauge corrections and sensor noise;
    ``change``: rolling while damping falls and/or leakage rises mid-episode), or ``paper`` (no
    extra disturbances), ``realistic``; or is a dict; or an ``EnvConfig`` built once at the edge
    (``load_env_config(name, version=...)``, a task's ``Task.configs[version]``), taken as it is with no file read.
    Any top-level key of it can be given as a keyword; every nested key is checked when the config loads. Every random draw comes from the
    env's seeded generator; the plant, the disturbances and the sensor noise each use their own
    child of the episode's ``SeedSequence``. ``render_mode="rgb_array"`` or ``"human"`` draws the recent
    displacement, velocity and gains (or valve command) with the severity so far; it works with
    ``gymnasium.wrappers.RecordVideo``, whose video plays at ``metadata["render_fps"]`` (20) frames a second
    whatever the drawing's speed. ``"human"`` shows at most 20 frames a second of wall time (an early frame waits
    for its moment); a loaded machine draws fewer (a frame's cost: the timing suite's render rows,
    docs/performance.md): a late frame is shown at once, never queued.

    ### Your own disturbance

    ``extra_disturbances=[...]`` (every environment, the VecEnv and the vector env take it) adds disturbances
    of your own after the config's: objects with a method ``apply(rng, profile, params)``
    (``millvib_env.envs.disturbances.Disturbance``). At each reset each draws from ``rng`` (the episode's
    disturbance stream, after the config's disturbances, so their draws are unchanged) and writes into the
    episode's ``profile``: the set-point ``profile.xd`` (m) and the rolling-force offset ``profile.dFL`` (N),
    one value per control period of ``profile.dt`` s, changed in place, and an event for the reset's info.
    A profile left with a non-finite value or another length is refused in one line.

    ```python
    class CoilWeld:  # a weld seam passes the roll gap: a 5 % force bump for 20 ms at a random time
        def apply(self, rng, profile, params):
            k = int(rng.uniform(0.1, 0.4) / profile.dt)
            profile.dFL[k:k + int(0.02 / profile.dt)] += 0.05 * params.FL
            profile.events.append(("weld", k * profile.dt, 0.05 * params.FL))

    env = gym.make("MillVib-GainSchedule-v1", config="rolling", extra_disturbances=[CoilWeld()])
    ```

    ### Your own reward

    ``reward_fn=`` (every environment, the VecEnv and the vector env take it) replaces the config's reward by
    yours: a callable that takes the period's terms (``millvib_env.envs.reward.RewardTerms``, one value per
    environment: ``vibration_rms_m_s``, ``tracking_rms_m``, ``effort``, ``offset``, ``terminated``,
    ``steps_left`` and ``config_reward``) and returns one finite reward per environment; anything else is
    refused in one line. The observation's running vibration measure and every metric in the info are the
    same with it or without it; the info's ``episode_return`` sums your rewards.

    ```python
    def quiet_first(terms):  # vibration only, in mm/s, and a flat 100 for leaving the envelope
        return -terms.vibration_rms_m_s * 1e3 - 100.0 * terms.terminated

    env = gym.make("MillVib-GainSchedule-v1", config="rolling", reward_fn=quiet_first)
    ```

    ### Your own envelope

    ``envelope_fn=`` (every environment, the VecEnv and the vector env take it) adds constraints of yours to the
    config's envelope: a callable that takes the period's terms (``millvib_env.envs.envelope.EnvelopeTerms``,
    one value per environment: ``x_abs_max_m``, ``pl_min_pa``, ``pl_max_pa``, ``x_m``, ``v_m_s``, ``pl_pa``,
    ``t_s`` and ``left_config``) and returns, per environment, whether the episode left it (True or False;
    anything else is refused in one line). An episode that leaves it ends as one that leaves the config's
    envelope: terminated, and scored as diverged.

    ```python
    def tight_gap(terms):  # a strip that tolerates 50 um of gap error once rolling has settled
        return (terms.t_s > 0.1) & (terms.x_abs_max_m > 50e-6)

    env = gym.make("MillVib-GainSchedule-v1", config="rolling", envelope_fn=tight_gap)
    ```

    ### Your own base controller

    ``base_controller=`` (every environment, the VecEnv and the vector env take it) sets the fixed controller
    the action works around: here the relative action's base (``actions.relative.base``: the zero action is
    exactly that controller, +-1 moves each gain by the config's ``decades``, one decade by default); in
    `ValveEnv` with ``residual=True`` the controller whose command the agent's is added to
    (``actions.residual_gains``). It takes an object with ``loop_gains()`` (KP, KI, KD, then KPL and KFF where it
    has them; ``millvib_env.envs.actions.LoopController``): a ``PIDGains`` or a fixed-gain baseline. Its
    episodes are those of the same gains given in the config, bit for bit; an agent, a plant-aware baseline or
    a controller given twice (here and in ``actions``) is refused in one line.

    ```python
    from millvib_env import PIDGains
    from millvib_env.catalog.factory import load_controller

    env = gym.make("MillVib-GainSchedule-v1", base_controller=load_controller("pid-pf-robust", version="v1"))
    env = gym.make("MillVib-Valve-v1", residual=True, base_controller=PIDGains(kp=8e5, ki=5e7, kd=300, kpl=6e-8))
    ```

    ## Version History

    * v1: the loop as commissioned (``gym.make("MillVib-GainSchedule-v1", config="rolling")``; the
      default of ``millvib benchmark``, ``tune``, ``train`` and ``sweep``). The PID is a digital
      controller at 2 kHz (``control_dt_s``) outside the plant: it samples a position transducer
      (0.5 um noise, 0.1 um resolution), a pressure transducer (1 kHz low-pass, 0.05 MPa noise) and the
      load cells (500 Hz low-pass, 5 kN noise), computes u = KP e + uI - KD v_f - KPL (p_m - pL_ref) +
      KFF F_m with a filtered derivative of the measured position, saturates it at the amplifier's
      +-10 V with conditional integration, and holds it one sample late (computation delay). The valve
      has dynamics (a second-order lag, -90 deg at 150 Hz, damping 0.7) and a spool stroke of 1.25 mm
      (configs/plant/commissioned.yaml). Ct is drawn up to 1e-10 m^3/(s Pa), where a +-10 V valve can
      still hold the gap with margin (the paper's 5e-9 needs 180 V). ``startup`` is a gap change under
      load: settled 0.3 mm out, the set-point led back to 0 at 2 mm/s, as a mill's reference generator
      does (the paper's 1 mm start holds the chamber above the supply pressure, which no valve can hold;
      at +-10 V it tested only the valve). An episode that leaves its envelope pays
      1000 per step not run (`envs.reward.DIVERGED_COST`). The observation's error, velocity,
      pressure and force are the loop's sampled sensors. Why: under v0 every controller commanded
      7-70 times the valve's rated stroke, and the verdicts did not hold on a physical loop
      (configs/env/v1/, docs/loop.md).
    * v0: the paper's analog loop inside the plant, an ideal valve without limit; tasks, pressure
      feedback, the plant change, the force feedforward, the relative action, the force observation
      and the offset penalty added within v0, each off by default (the default episode is unchanged,
      bit for bit on the machine that saved it).
    """

    mode = "gain"


class ValveEnv(MillVibEnv):
    """## Description

    Direct valve control of the rolling mill's hydraulic screw-down cylinder (the plant of
    `GainScheduleEnv`): every control period (1 ms) the agent commands the servo-amplifier input.
    With ``residual=True`` the command is added to a fixed controller's (the paper's PID by default;
    ``actions.residual_gains`` takes [KP, KI, KD], + KPL for pressure feedback, + KFF for the force
    feedforward; or give the controller as an object, ``base_controller=``, see `GainScheduleEnv`): the agent
    learns a correction.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: u_agent = a * 100 V (``actions.u_range_v``; residual mode:
    ``actions.residual_range_v``). The valve spool moves xv = Ksv Kp1 u (1.25 mm per 10 V). The
    command is held over the period. Finite actions outside [-1, 1] are clipped; NaN, inf or a
    wrong shape raise ValueError.

    ## Observation Space

    ``Box(-1, 1, (6,), float32)`` (7 in residual mode): channels 0-4 as in `GainScheduleEnv`
    (error, velocity, acceleration, pressure, running band-limited vibration), then the last
    action; in residual mode also the PID's own command (V / residual range, clipped). Optional
    pump phase, true parameters and the load cells' force as in `GainScheduleEnv`. Optional preview
    (``observation.preview_samples``, a list of look-aheads k in control samples): per k, the rolling
    force's change (signed-log, as the force channel) and the set-point's change (signed-log, as the
    error) from the hold that starts now to the one k samples ahead: what an entry-thickness gauge
    upstream of the stand and the pass schedule tell a controller. By default the force's is the
    episode's own course, exact (eccentricity included); ``observation.preview_gauge: measured``
    gives it as a gauge measures it (`envs.gauge`: a timing error from the strip speed's error,
    1 ms RMS; a 10 % force-model error per change; 10 kN RMS of noise; no eccentricity; a mapping
    sets each, and ``failed: true`` loses the gauge's signal for the episode), from the episode's own
    gauge stream. The set-point's course is exact either way.
    Optional history (``observation.history_samples``, a list of lags k in agent steps): per k, the
    measured channels (error, velocity, acceleration, pressure, last action, PID command, load force,
    those present) as they were k steps ago, appended after the others (names ``<channel>_lag_<k>``; an
    episode's first observation fills the steps before it). Optional memory (``observation.history_filters``,
    a list of time constants tau in agent steps): per tau, the same channels' exponential moving averages
    and those of their squares (each moves by 1/tau of the step's value a step; names
    ``<channel>_mean_<tau>`` and ``<channel>_meansq_<tau>``), appended last; an episode's first observation
    starts them.
    On the sampled loop (v1), ``observation.loop_sample`` says which of the controller's samples the
    position, velocity, pressure, PID command and force channels carry: ``"previous"`` (the default)
    the one it took at the period's start, one sample older than the one the action is added to;
    ``"current"`` the one it takes at the period's end, together with the action (as one program on
    the mill's controller reads its inputs once for both). The plant's course is the same either way.

    ## Rewards

    As `GainScheduleEnv`, with effort = a^2 (the command's size) instead of the gain changes.

    ## Starting State

    As `GainScheduleEnv`; without residual mode no PID acts.

    ## Episode End

    As `GainScheduleEnv`; truncation after 0.5 s = 500 steps.

    ## Arguments

    ```python
    env = gym.make("MillVib-Valve-v0", residual=True, config="default")
    ```

    ## Version History

    * v1: the loop as commissioned (see `GainScheduleEnv`): the agent's command is added to the digital
      controller's (residual) or drives the valve alone, every 0.5 ms (the loop's 2 kHz), and is
      saturated with it at the amplifier's +-10 V; ``u_range_v`` and ``residual_range_v`` keep their
      meaning. 1000 steps per ``startup`` episode, 2000 on ``rolling`` and ``change``. Later, an option
      that changes no default: ``observation.preview_gauge`` (the preview as a gauge measures it; ``exact``,
      the default, gives the same episodes bit for bit as before).
    * v0: initial release (the paper's analog loop, an ideal valve without limit).
    """

    mode = "valve"
