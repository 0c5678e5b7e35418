"""The environments' engine: N plants advanced together, shared by the single and the vector env.

`MillVibCore` holds N independent episodes (one per environment) as arrays and advances them all
in one compiled call (`plant.kernel.advance_batch`, which calls the one `plant_rhs`). The single
Gymnasium env is a core with N = 1 and the native VecEnv a core with N = n_envs, so both run the
same code and give the same trajectories for the same seeds. The parts live in their own modules:
the gain/action mapping (`actions`), the episode draw (`episode`), the observation (`observation`)
and the reward (`reward`).

Randomness: every environment has its own generator (gymnasium's `np_random`, reseeded by
``reset(seed=...)``). At each reset it draws one episode seed; the episode's plant, disturbances
and sensor noise each draw from their own child of that seed's SeedSequence.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from millvib_env import _interrupt
from millvib_env._checks import shown
from millvib_env.envs.config import EnvConfig
from millvib_env.envs.core_settings import MAX_BATCH_BYTES, core_settings
from millvib_env.envs.disturbances import EpisodeProfile, user_disturbances
from millvib_env.envs.envelope import EnvelopeTerms, left_flags, user_envelope
from millvib_env.envs.episode import check_reset_options, draw_episode
from millvib_env.envs.feedforward import ChannelFeedforward
from millvib_env.envs.gauge import gauge_force
from millvib_env.envs.metrics import record_levels
from millvib_env.envs.observation import Observer
from millvib_env.envs.period import record_actuator, summarize_period
from millvib_env.envs.reads import EpisodeReads
from millvib_env.envs.reward import Reward
from millvib_env.loop import kernel as loop_kernel
from millvib_env.loop.kernel import K_FM, K_PM, K_UCTRL, K_VF, K_XM, NCS, peek_samples
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains
from millvib_env.plant import kernel
from millvib_env.plant.kernel import rhs_vector
from millvib_env.plant.model import (A_ACC, A_PS, A_U, C_EA, C_EP, C_EW, C_KD, C_KFF, C_KI, C_KP, C_KPL, C_PID, C_UEXT,
                                     IPL, IUI, IV, IX, NAUX, NC, NPACK, NY, P_FL, P_PF, P_PS, P_UMAX, drive_vector,
                                     pack, rated_flow, settled_state, state_scale)
from millvib_env.severity import iso_zone

__all__ = ["MillVibCore", "MAX_BATCH_BYTES"]

#: where each gain of a gain-schedule action goes in the drive vector
GAIN_COLUMNS = {"kp": C_KP, "ki": C_KI, "kd": C_KD, "kpl": C_KPL, "kff": C_KFF}

#: how much recent history (s) the render keeps
RENDER_WINDOW_S = 0.1
#: the start of an episode reported apart from the rest (s): the transient of a 1 mm start or of a
#: plant change's onset lives there; episodes shorter than twice this have no split
TRANSIENT_S = 0.1


class MillVibCore(EpisodeReads):
    """N episodes of the screw-down plant in one of two modes: 'gain' or 'valve'."""

    def __init__(self, n: int, mode: str, config: EnvConfig, *, residual: bool = False,
                 observe_params: bool | None = None, observe_phase: bool | None = None,
                 extra_disturbances: Sequence | None = None, reward_fn: Any = None, envelope_fn: Any = None):
        #: what the batch is, fixed (`envs.core_settings`: gymnax's EnvParams); the rest of the core is its state
        self.settings = s = core_settings(n, mode, config, residual=residual, observe_params=observe_params,
                                          observe_phase=observe_phase)
        dist = config.disturbances
        self.disturbances, noise, delay = list(dist.profile), dist.sensor_noise, dist.delay_steps
        self.n_builtin = len(self.disturbances)  # then a user's own (`envs.disturbances.Disturbance`), in order
        self.disturbances += user_disturbances(extra_disturbances)
        self.action_space = spaces.Box(-1.0, 1.0, (s.act_dim,), dtype=np.float32)
        self.observer = Observer(mode, residual=s.residual, gain_names=s.gain_map.names,
                                 observe_phase=s.observe_phase, observe_params=s.observe_params,
                                 observe_force=s.observe_force, noise=noise, delay=delay, n=s.n,
                                 preview_samples=config.observation.preview_samples,
                                 history_samples=config.observation.history_samples,
                                 history_filters=config.observation.history_filters)
        self.obs_names = self.observer.names
        #: the fixed feedforward under a residual action (`envs.feedforward`), read from the observation the agent
        #: acted on; None without one
        self.feedforward = None
        if config.actions.residual_feedforward:
            if not s.residual:
                raise ValueError("actions.residual_feedforward is given, but the environment is not a residual valve "
                                 "environment: a feedforward runs under the residual valve action only "
                                 "(MillVib-Valve with residual=True)")
            self.feedforward = ChannelFeedforward.from_mapping(config.actions.residual_feedforward, self.obs_names)
        self.observation_space = spaces.Box(-1.0, 1.0, (len(self.obs_names),), dtype=np.float32)
        self.reward = Reward(config.reward, period_s=s.period_s, sample_rate_hz=config.sample_rate_hz, n=s.n,
                             user=reward_fn)
        self.envelope_fn = user_envelope(envelope_fn)
        self._allocate_state()

    def _allocate_state(self) -> None:
        """Every environment's state, zeroed: its generator and plant, the plant's and the loop's states, the
        episode's courses and records. A reset fills them."""
        st = self.settings
        config, n = st.cfg, st.n
        self.np_random: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(n)]
        self.params: list[MillParams] = [config.base_params] * n
        self._plant_info: list[dict] = [{}] * n
        self.profiles: list[EpisodeProfile | None] = [None] * n
        self.scenario: list[str | None] = [None] * n
        self.started = np.zeros(n, dtype=bool)
        self.P = np.zeros((n, NPACK))
        self.C = np.zeros((n, NC))
        self.Y = np.zeros((n, NY))
        self.F = np.zeros((n, NY))
        self.H = np.full(n, kernel.H_INIT)
        self.T = np.zeros(n)
        self.ATOL = np.zeros((n, NY))
        self.XD = np.zeros((n, st.n_ctrl + st.n_sub))
        self.DFL = np.zeros((n, st.n_ctrl + st.n_sub))
        #: the force course each episode's measured preview predicts (`envs.gauge`)
        self.GF = np.zeros((n, st.n_ctrl + st.n_sub)) if st.gauge is not None else None
        self.k = np.zeros(n, dtype=np.int64)
        self.sq_err_sum = np.zeros(n)
        self.acc_trace = np.zeros((n, st.trace_samples))  # + the sample at t = 0
        self.n_trace = np.zeros(n, dtype=np.int64)
        self.last_action = np.zeros((n, st.act_dim))
        self.seen = np.zeros((n, len(self.obs_names)), np.float32)  # the observation the agent acts on
        self.u_ff = np.zeros(n)  # the feedforward's command (V) of the period under way
        self.gains = np.zeros((n, st.gain_map.dim))
        self.ep_return = np.zeros(n)
        self.YS = np.zeros((n, st.n_samp + 1, NY))
        self.AUXS = np.zeros((n, st.n_samp + 1, NAUX))
        self.status = np.zeros(n, dtype=np.int64)
        self.n_valid = np.zeros(n, dtype=np.int64)
        if st.loop is not None:
            self.CS = np.zeros((n, NCS))  # the digital controllers' states (`loop.kernel.CS_NAMES`)
            self.LS = st.loop.vector()
            self.NOISE = np.zeros((n, st.n_ctrl + st.n_sub, 3))  # the sensors' standard normals
        #: the episode's actuator record: max |u| (V), samples at the limit, samples, max |xv| (m), max |QL|
        #: (m^3/s), min and max pL (Pa)
        self.actuator = np.zeros((n, 7))
        self.n_steps = np.zeros(n, dtype=np.int64)
        #: the period's summary (`envs.period.summarize_period`): vibration and error mean squares, max |x|,
        #: min and max pL, per environment
        self._period = tuple(np.zeros(n) for _ in range(5))
        #: when True, every step's info carries the period's measured signals ("signals"), as a mill's
        #: data acquisition records them (position, velocity, acceleration, pressures, valve command)
        self.record_signals = False
        #: when True, the first environment keeps its recent samples for `render` (`envs.rendering`): the
        #: environments set it where a render mode is given, and `render` where it is called without one set
        self.keep_history = False
        self.history: list[dict] = [{}]
        # index arrays every step uses (the environments and a period's control samples), and all-active flags
        self._rows = np.arange(n)[:, None]
        self._sub = np.arange(st.n_sub)
        self._all = np.arange(n)
        self._active = np.ones(n, dtype=np.bool_)

    # ------------------------------------------------------------------------------------------
    def gains_from_action(self, action: np.ndarray) -> np.ndarray:
        """Map gain-schedule actions in [-1, 1]^k to gains (KP, KI, KD[, KPL]) (`GainMap`)."""
        return self.settings.gain_map.gains(action)

    def action_from_gains(self, gains: np.ndarray) -> np.ndarray:
        """Inverse of `gains_from_action` (gains outside the bounds are clipped)."""
        return self.settings.gain_map.action(gains)

    def current_params(self, i: int) -> dict:
        """The plant of environment i now: c1 and Ct move during a plant change."""
        p = self.params[i]
        profile = self.profiles[i]
        change = profile.change if profile is not None else None
        if change is None:  # every step's info carries it: a copy of the episode's, not a new build
            return dict(self._plant_info[i])
        c1, ct = change.values_at(self.T[i], p)
        return {**self._plant_info[i], "c1": c1, "Ct": ct}

    def _step_infos(self) -> list[dict]:
        """Every environment's step info, {"params": `current_params(i)`}: where the plant holds still, a copy of the
        episode's dict made in the loop itself (a step of 200 environments made 200 method calls for it)."""
        return [{"params": info.copy() if profile is None or profile.change is None else self.current_params(i)}
                for i, (info, profile) in enumerate(zip(self._plant_info, self.profiles))]

    # ------------------------------------------------------------------------------------------
    def seed_env(self, i: int, seed: int | None) -> None:
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
            raise ValueError(f"seed = {shown(seed)} is invalid: a non-negative integer or None")
        self.np_random[i], _ = seeding.np_random(None if seed is None else int(seed))

    def reset_env(self, i: int, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start a new episode in environment i (a new plant, disturbances, initial state)."""
        st = self.settings
        options = check_reset_options(options, st.cfg)
        if seed is not None:
            self.seed_env(i, seed)
        episode_seed = int(self.np_random[i].integers(2**63 - 1))
        ep = draw_episode(st.cfg, self.disturbances, episode_seed, st.n_ctrl, options, self.n_builtin)
        params, profile = ep.params, ep.profile
        self.observer.start_noise(i, ep.noise_rng, st.max_steps + 1)  # an observation at reset and per step
        self.params[i] = params
        # info["params"]: the episode's plant (c1 and Ct replaced while it changes: `current_params`)
        self._plant_info[i] = {"c1": params.c1, "Ct": params.Ct, "beta_e": params.beta_e, "mt": params.mt,
                               "FL": params.FL, "pulse_amp": params.pulse_amp}
        self.profiles[i] = profile
        self.scenario[i] = ep.scenario
        self.P[i] = pack(params)
        self.ATOL[i] = st.rtol * state_scale(params)
        self.Y[i] = ep.y0
        self.H[i] = kernel.H_INIT
        self.T[i] = 0.0
        self.XD[i, :st.n_ctrl] = profile.xd
        self.XD[i, st.n_ctrl:] = profile.xd[-1]
        self.DFL[i, :st.n_ctrl] = profile.dFL
        self.DFL[i, st.n_ctrl:] = profile.dFL[-1]
        if self.GF is not None and st.gauge is not None:
            gf = gauge_force(profile.dFL, np.random.default_rng(ep.gauge_seed), st.cfg.control_dt_s, st.gauge)
            self.GF[i, :st.n_ctrl] = gf
            self.GF[i, st.n_ctrl:] = gf[-1]
        if st.mode == "gain":
            # the paper's PID (KPL, KFF at their lowest bounds), or the base gains of a relative action
            self.gains[i] = st.gain_map.start_gains(PAPER_GAINS.to_array())
            start = PIDGains(**dict(zip(st.gain_map.names, (float(g) for g in self.gains[i]))))
        else:
            start = st.residual_gains
            self.gains[i] = np.resize(start.to_array(), self.gains.shape[1]) if st.residual else 0.0
        pl_ref = settled_state(params, xd=float(profile.xd[0]))[IPL]  # steady operation's load pressure
        c = drive_vector(start, pid_on=st.mode == "gain" or st.residual, pl_ref=pl_ref, change=profile.change)
        c[C_EA], c[C_EW], c[C_EP] = profile.ecc_amp_n, profile.ecc_omega, profile.ecc_phase
        self.C[i] = c
        plant_c = self.C[i]
        if st.loop is not None:  # the digital controller takes over the integral term and the hold
            u0 = float(self.Y[i, IUI]) if c[C_PID] else 0.0
            self.Y[i, IUI] = 0.0
            self.CS[i] = loop_kernel.start_state(self.Y[i], float(profile.dFL[0]) + float(self._eccentricity(i, 0.0)),
                                                 u0, params.u_max)
            self.NOISE[i] = ep.loop_rng.standard_normal(self.NOISE.shape[1:])
            plant_c = loop_kernel.plant_drive(self.C[i], self.CS[i, loop_kernel.K_UAPP])
        self.actuator[i] = (0.0, 0.0, 0.0, 0.0, 0.0, np.inf, -np.inf)
        self.k[i] = 0
        self.reward.start(i)
        self.sq_err_sum[i] = 0.0
        # the record starts at t = 0, as simulate()'s does (the paper's start is at rest: a = 0)
        self.acc_trace[i, 0] = rhs_vector(0.0, self.Y[i], self.P[i], plant_c)[IV]
        self.n_trace[i] = 1
        self.last_action[i] = 0.0
        self.ep_return[i] = 0.0
        self.started[i] = True
        if i == 0:
            self.history[0] = {"t": [0.0], "x": [np.array([ep.x0])], "v": [np.zeros(1)],
                               "gains": [self.gains[0].copy()], "u": [0.0]}
        if st.fresh:  # the first sample's readings, which the controller takes at t = 0 with the first action
            obs = self._observe_sample(np.array([i]), a=np.zeros(1))
        else:
            obs = self._observe(np.array([i]), e=np.array([profile.xd[0] - ep.x0]), v=np.zeros(1), a=np.zeros(1),
                                pL=np.array([self.Y[i, IPL]]), u_pid=np.zeros(1))
        info = {"params": self.current_params(i), "scenario": ep.scenario,
                "disturbances": list(profile.events), "x0": ep.x0}
        first = self.observer.start(i, obs[0])
        self.seen[i] = first
        return first, info

    # ------------------------------------------------------------------------------------------
    def check_actions(self, actions: Any) -> np.ndarray:
        st = self.settings
        try:
            a = np.asarray(actions, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond a float
            raise ValueError(f"action = {shown(actions)} is invalid: numbers in [-1, 1] of shape ({st.act_dim},)") \
                from None
        if a.shape == (st.act_dim,) and st.n == 1:
            a = a[None, :]
        if a.shape != (st.n, st.act_dim):
            raise ValueError(f"action has shape {np.shape(actions)}; expected ({st.n}, {st.act_dim})"
                             + (f" or ({st.act_dim},)" if st.n == 1 else ""))
        if not np.isfinite(a).all():
            raise ValueError(f"action contains NaN or inf: {a.tolist()}; allowed range is [-1, 1]")
        return np.minimum(np.maximum(a, -1.0), 1.0)  # finite actions outside the Box are clipped, as Box actions are

    def step(self, actions: Any):
        """Advance every environment by one agent period. Returns obs, reward, terminated, truncated, infos."""
        st = self.settings
        _interrupt.check()  # a Ctrl-C a library swallowed (numba's compiler, a solver) ends the run here
        if not self.started.all():
            raise ValueError("step() before reset(): call reset() to start an episode first")
        a = self.check_actions(actions)
        n = st.n
        if st.mode == "gain":
            self.gains = st.gain_map.gains(a)
            for j, name in enumerate(st.gain_map.names):
                self.C[:, GAIN_COLUMNS[name]] = self.gains[:, j]
            effort = np.mean(np.abs(a - self.last_action), axis=1)
        else:
            self.C[:, C_UEXT] = self._valve_command(a)
            effort = a[:, 0] ** 2
        self.last_action = a

        cols = self.k[:, None] * st.n_sub + self._sub
        rows = self._rows
        xd_step, dfl_step = self.XD[rows, cols], self.DFL[rows, cols]
        active = self._active
        p_max = 10.0 * float(self.P[:, P_PS].max())  # numerical guard only; the envelope below is physical
        if st.loop is None:
            kernel.advance_batch(self.P, self.C, self.Y, self.F, self.H, self.T, xd_step, dfl_step, active,
                                 st.cfg.control_dt_s, st.spp, st.rtol, self.ATOL, p_max, st.max_kernel_steps,
                                 self.YS, self.AUXS, self.status, self.n_valid, self.n_steps)
        else:
            loop_kernel.advance_loop_batch(self.P, self.C, self.Y, self.F, self.H, self.T, xd_step, dfl_step,
                                           self.NOISE, self.k * st.n_sub, self.CS, self.LS, active, st.spp,
                                           st.rtol, self.ATOL, p_max, st.max_kernel_steps, self.YS, self.AUXS,
                                           self.status, self.n_valid, self.n_steps)

        failed = self.status != 0
        if failed.any():
            self._hold_last_good(failed)
        vib_ms, err_ms, x_abs, pl_lo, pl_hi = self._period
        summarize_period(self.YS, self.AUXS, xd_step, st.spp, self.reward.sos, self.reward.zi, self.acc_trace,
                         self.n_trace, vib_ms, err_ms, x_abs, pl_lo, pl_hi)
        self._record_actuator(pl_lo, pl_hi)
        last = self.YS[:, -1, :]
        ps = self.P[:, P_PS]
        terminated = failed | (x_abs > st.x_max) | (pl_lo < st.p_min) | (pl_hi > st.p_max_factor * ps)
        if self.envelope_fn is not None:  # a user's own constraints, on top of the config's envelope
            terminated = terminated | self._users_envelope(x_abs, pl_lo, pl_hi, last, terminated)
        offset = np.mean(a ** 2, axis=1) if st.mode == "gain" and (self.reward.w_off or self.reward.user) else None
        reward = self.reward.step(vib_ms, err_ms, effort, terminated, offset, remaining=st.max_steps - self.k - 1)
        self.sq_err_sum += err_ms * st.n_samp
        self.k += 1
        truncated = (self.k >= st.max_steps) & ~terminated
        self.ep_return += reward

        if st.loop is None:
            u_last = self.AUXS[:, -1, A_U]
            u_pid = u_last - self.C[:, C_UEXT] if st.residual else np.zeros(n)
            obs = self._observe(self._all, e=xd_step[:, -1] - last[:, IX], v=last[:, IV],
                                a=self.AUXS[:, -1, A_ACC], pL=last[:, IPL], u_pid=u_pid)
        elif st.fresh:
            obs = self._observe_sample(self._all, a=self.AUXS[:, -1, A_ACC])
        else:  # what the controller read at its last sample: the same sensors
            cs = self.CS
            obs = self._observe(self._all, e=xd_step[:, -1] - cs[:, K_XM], v=cs[:, K_VF], a=self.AUXS[:, -1, A_ACC],
                                pL=cs[:, K_PM], u_pid=cs[:, K_UCTRL] if st.residual else np.zeros(n))
        out_obs = self.observer.push(obs)
        self.seen[:] = out_obs

        ended = np.flatnonzero(terminated | truncated)
        metrics = dict(zip(ended.tolist(), self.episode_metrics_batch(ended, terminated[ended]))) if ended.size else {}
        infos = self._step_infos()
        if self.record_signals:
            for i in range(n):
                infos[i]["signals"] = self._signals(i, np.repeat(xd_step[i], st.spp))
        for i, m in metrics.items():
            infos[i].update(m)
        self._record_history()
        return out_obs, reward.astype(np.float64), terminated, truncated, infos

    def _valve_command(self, a: np.ndarray) -> np.ndarray:
        """The valve action's volts, and the fixed feedforward under a residual (`envs.feedforward`), computed from
        the observation the action was taken on and held within the valve action's full scale, as a valve action is."""
        st = self.settings
        if self.feedforward is None:
            return a[:, 0] * st.u_range
        ff = self.feedforward.command_v(self.seen)
        self.u_ff = np.minimum(np.maximum(ff, -st.ff_limit), st.ff_limit)
        return a[:, 0] * st.u_range + self.u_ff

    def _hold_last_good(self, failed: np.ndarray) -> None:
        """In the environments whose period failed, hold the last good sample over the samples not written, so
        nothing non-finite reaches the filters (and the plant state, if it went non-finite)."""
        samples, aux = self.YS[:, 1:, :], self.AUXS[:, 1:, :]
        valid = np.arange(1, self.settings.n_samp + 1)[None, :] < self.n_valid[:, None]
        last = np.maximum(self.n_valid - 1, 0)
        for b in np.flatnonzero(failed):
            good_y = self.YS[b, last[b]] if np.all(np.isfinite(self.YS[b, last[b]])) else self.YS[b, 0]
            good_a = self.AUXS[b, last[b]] if np.all(np.isfinite(self.AUXS[b, last[b]])) else self.AUXS[b, 0]
            samples[b, ~valid[b]] = good_y
            aux[b, ~valid[b]] = good_a
            if not np.all(np.isfinite(self.Y[b])):
                self.Y[b] = good_y

    def _signals(self, i: int, xd: np.ndarray) -> dict:
        """The period's samples of environment i as a mill's data acquisition records them: position,
        velocity, acceleration, chamber and supply pressure, valve command, set-point, and the
        rolling force FL(t) from the load cells (nominal + steps + eccentricity). The PID's integral
        term and the bristle state are not measurements and are not included."""
        st = self.settings

        t = self.T[i] - st.period_s + st.dt_sample * np.arange(1, st.n_samp + 1)
        k0 = (self.k[i] - 1) * st.n_sub
        load = self.P[i, P_FL] + np.repeat(self.DFL[i, k0:k0 + st.n_sub], st.spp)
        if self.C[i, C_EA] != 0.0:
            load = load + self._eccentricity(i, t)
        return {"t": t, "x": self.YS[i, 1:, IX].copy(), "v": self.YS[i, 1:, IV].copy(),
                "a": self.AUXS[i, 1:, A_ACC].copy(), "pL": self.YS[i, 1:, IPL].copy(),
                "u": self.AUXS[i, 1:, A_U].copy(), "ps": self.AUXS[i, 1:, A_PS].copy(), "xd": xd.copy(),
                "FL": load}

    def next_sample(self, idx: np.ndarray) -> np.ndarray:
        """The readings the digital controller of environments `idx` takes at its next sample, before it takes
        them (`loop.kernel.peek_samples`: the same numbers, with that sample's set-point, force step and noise):
        rows (x_m, v_f, p_m, F_m, the PID's command in V), one per environment (v1 only)."""
        idx = np.asarray(idx, np.int64)
        col = self.k[idx] * self.settings.n_sub
        got = np.empty((len(idx), 5))
        peek_samples(idx, self.T, self.Y, self.C, self.CS, self.LS, self.XD[idx, col], self.DFL[idx, col],
                     self.NOISE, col, got)
        return got

    def _observe_sample(self, idx: np.ndarray, *, a) -> np.ndarray:
        """Observations of environments `idx` from the readings the controller takes at its next sample."""
        st = self.settings
        xm, vf, pm, fm, u_ctrl = self.next_sample(idx).T
        xd = self.XD[idx, self.k[idx] * st.n_sub]
        return self._observe(idx, e=xd - xm, v=vf, a=a, pL=pm, u_pid=u_ctrl if st.residual else np.zeros(len(idx)),
                             force=fm)

    def _observe(self, idx: np.ndarray, *, e, v, a, pL, u_pid, force=None) -> np.ndarray:
        st = self.settings
        if st.mode == "gain":
            control = st.gain_map.action(self.gains[idx])
        else:
            control = self.last_action[idx, 0]
        params = [(self.params[i].c1, self.params[i].Ct) for i in idx] if st.observe_params else None
        if params is not None and any(self.profiles[i] is not None and self.profiles[i].change for i in idx):
            params = [tuple(self.current_params(i)[k] for k in ("c1", "Ct")) for i in idx]
        return self.observer.build(idx, e=e, v=v, a=a, pL=pL, ps=self.P[idx, P_PS],
                                   vib_rms=self.reward.vib_rms[idx], control=control,
                                   u_pid=u_pid / st.u_range, phase=2 * np.pi * self.P[idx, P_PF] * self.T[idx],
                                   params=params, force=(self._observed_force(idx) if force is None else force)
                                   if st.observe_force else None,
                                   preview=self.preview(idx) if self.observer.preview_samples else None)

    def preview(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The preview of environments `idx` (`ObservationSettings.preview_samples`): the rolling force's change
        (N: force steps and eccentricity) and the set-point's (m) from the hold that starts now to the one that
        starts k control samples ahead, for each look-ahead k; beyond the episode's end the last values hold. The
        force is the plant's own (exact) or, where the preview is measured, the gauge's (`envs.gauge`)."""
        st = self.settings
        ks = np.asarray(self.observer.preview_samples)
        now = self.k[idx] * st.n_sub
        last = self.DFL.shape[1] - 1
        cols = np.minimum(now[:, None] + ks[None, :], last)
        rows = np.asarray(idx)[:, None]
        dt = st.cfg.control_dt_s
        t_now = self.T[idx]
        forces = self.DFL if self.GF is None else self.GF
        force_now = forces[idx, np.minimum(now, last)]
        force_then = forces[rows, cols]
        if st.gauge is None or st.gauge.eccentricity:
            force_now = force_now + self._eccentricity(idx, t_now)
            force_then = force_then + self._eccentricity(rows, t_now[:, None] + ks[None, :] * dt)
        xd_now = self.XD[idx, np.minimum(now, last)]
        return force_then - force_now[:, None], self.XD[rows, cols] - xd_now[:, None]

    def _observed_force(self, idx: np.ndarray) -> np.ndarray:
        """The force channel: the load cells' reading in the sampled loop, else the true deviation."""
        return self.CS[idx, K_FM] if self.settings.loop is not None else self.force_deviation(idx)

    def force_deviation(self, idx: np.ndarray) -> np.ndarray:
        """The load cells' rolling-force deviation FL(t) - FL (N) of environments `idx` now: the force
        step of the period just integrated plus the roll eccentricity at the current time."""
        col = np.clip(self.k[idx] * self.settings.n_sub - 1, 0, self.DFL.shape[1] - 1)
        return self.DFL[idx, col] + self._eccentricity(idx, self.T[idx])

    def _users_envelope(self, x_abs, pl_lo, pl_hi, last, terminated) -> np.ndarray:
        """Whether each environment left the user's envelope (`envs.envelope`) in this period."""
        assert self.envelope_fn is not None
        terms = EnvelopeTerms(x_abs.copy(), pl_lo.copy(), pl_hi.copy(), last[:, IX].copy(), last[:, IV].copy(),
                              last[:, IPL].copy(), self.T.copy(), terminated.copy())
        return left_flags(self.envelope_fn, terms, self.settings.n)

    def episode_metrics(self, i: int, terminated: bool) -> dict:
        """Episode-end metrics of environment i (`episode_metrics_batch` of one environment)."""
        return self.episode_metrics_batch(np.array([i]), np.array([terminated]))[0]

    def episode_metrics_batch(self, idx: np.ndarray, terminated: np.ndarray) -> list[dict]:
        """Episode-end metrics of environments `idx` (their episodes ended: `terminated` says which
        diverged): severity over the whole episode (`vibration_severity`), over its first TRANSIENT_S
        and over the rest, the pump line's and the 10-100 Hz band's levels, tracking RMS, ISO zone.
        A diverged episode is scored on the record up to its end (its last good sample held), at rest
        after that if it ended in its first 0.1 s; parts a too short record cannot give are inf.

        Records of equal length (episodes that end together) are transformed together, on the
        plant threads (`threads.use_threads`): the same numbers as one environment at a time."""
        fs = self.settings.cfg.sample_rate_hz
        split = int(round(TRANSIENT_S * fs)) + 1
        records = []
        for i, term in zip(idx, terminated):
            acc = self.acc_trace[i, :int(self.n_trace[i])]
            if term and acc.size < split:
                # scored as if the mill stopped where it left its envelope: at rest for the rest of the
                # shortest record the 10 Hz band edge allows (0.1 s), so the cost stays finite and large
                acc = np.concatenate([acc, np.zeros(split - acc.size)])
            records.append(acc)
        levels = record_levels(records, fs, np.array([self.params[i].pulse_freq for i in idx]), split)
        out = []
        for j, (i, term) in enumerate(zip(idx, terminated)):
            sev = float(levels["broadband"][j])
            trk = math.sqrt(self.sq_err_sum[i] / max(int(self.n_trace[i]), 1))
            out.append({"severity": sev, "tracking_rms_um": trk * 1e6,
                        "iso_zone": iso_zone(sev) if math.isfinite(sev) else "D",
                        "severity_start": float(levels["start"][j]), "severity_rest": float(levels["rest"][j]),
                        "pump_line_mm_s": float(levels["pump_line"][j]), "low_band_mm_s": float(levels["low_band"][j]),
                        "diverged": bool(term), "episode_return": float(self.ep_return[i]),
                        "episode_steps": int(self.k[i]), "scenario": self.scenario[i], **self.actuator_metrics(i)})
        return out

    def acceleration_record(self, i: int) -> np.ndarray:
        """The acceleration samples of environment i's episode so far (m/s^2, from t = 0)."""
        return self.acc_trace[i, :int(self.n_trace[i])].copy()

    def _record_actuator(self, pl_lo: np.ndarray, pl_hi: np.ndarray) -> None:
        """Add this period to each episode's actuator record (`actuator`): the command's largest
        magnitude and its samples at the amplifier's limit, the largest port opening and flow, the
        pressure's range; from the 10 kHz samples the period wrote."""
        record_actuator(self.AUXS, self.n_valid, self.P[:, P_UMAX], pl_lo, pl_hi, self.actuator)

    def actuator_metrics(self, i: int) -> dict:
        """Environment i's actuator record as episode metrics: the valve command's largest magnitude (V) and
        its share of time at the amplifier's limit, the spool stroke used (the largest port opening, m), the
        peak flow against the valve's rated flow (`plant.model.rated_flow`), the chamber pressure's range (Pa)."""
        rec = self.actuator[i]
        return {"command_max_abs_v": float(rec[0]), "command_at_limit_share": float(rec[1] / max(rec[2], 1.0)),
                "spool_stroke_m": float(rec[3]), "peak_flow_ratio": float(rec[4] / rated_flow(self.params[i])),
                "pl_min_pa": float(rec[5]), "pl_max_pa": float(rec[6])}

    def _record_history(self) -> None:
        """Keep the first environment's recent samples for rendering (where `keep_history`)."""
        if not self.keep_history:
            return
        h = self.history[0]
        h["t"].append(self.T[0])
        h["x"].append(self.YS[0, 1:, IX].copy())
        h["v"].append(self.YS[0, 1:, IV].copy())
        h["gains"].append(self.gains[0].copy())
        h["u"].append(float(self.AUXS[0, -1, A_U]))
        keep = max(2, int(RENDER_WINDOW_S / self.settings.period_s) + 1)
        for key in h:
            del h[key][:-keep]
