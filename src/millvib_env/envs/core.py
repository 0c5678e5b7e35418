"""The environments' engine: N plants advanced together, shared by the single and the vector env.

`MillVibCore` holds N independent episodes (one per environment) as arrays and advances them all
in one compiled call (`plant.kernel.advance_batch`, which calls the one `plant_rhs`). The single
Gymnasium env is a core with N = 1 and the native VecEnv a core with N = n_envs, so both run the
same code and give the same trajectories for the same seeds.

Randomness: every environment has its own generator (gymnasium's `np_random`, reseeded by
``reset(seed=...)``). At each reset it draws one episode seed; the episode's plant, disturbances
and sensor noise each draw from their own child of that seed's SeedSequence.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from scipy import signal as ssig

from millvib_env.envs.config import EnvConfig
from millvib_env.envs.disturbances import EpisodeProfile, build_disturbances
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains
from millvib_env.plant import kernel
from millvib_env.plant.kernel import rhs_vector
from millvib_env.plant.integrate import MAX_STEPS_PER_SECOND, DEFAULT_RTOL_FAST, state_scale
from millvib_env.plant.model import (A_ACC, A_U, C_EA, C_EP, C_EW, C_KD, C_KI, C_KP, C_UEXT, IPL, IV, IX, NAUX,
                                     NC, NPACK, NY, P_PF, P_PS, drive_vector, initial_state, pack)
from millvib_env.severity import iso_zone, vibration_severity

__all__ = ["MillVibCore", "slog", "GAIN_NAMES", "OBS_SCALES", "PARAM_OBS_RANGES", "action_from_gains",
           "log_gain_bounds"]

#: with observe_params, log c1 and log Ct are mapped linearly from these ranges to [-1, 1]
PARAM_OBS_RANGES = {"c1": (1.25e5, 2.25e6), "Ct": (5e-16, 5e-9)}
#: how much recent history (s) the render keeps
RENDER_WINDOW_S = 0.1

GAIN_NAMES = ("kp", "ki", "kd")


def log_gain_bounds(config: EnvConfig) -> tuple[np.ndarray, np.ndarray]:
    """log10 of the (KP, KI, KD) bounds of the gain-schedule action (config section `actions`)."""
    acts = config["actions"]
    return np.log10([acts[k][0] for k in GAIN_NAMES]), np.log10([acts[k][1] for k in GAIN_NAMES])


def action_from_gains(gains, config: EnvConfig) -> np.ndarray:
    """The gain-schedule action in [-1, 1]^3 that maps to (KP, KI, KD); gains outside the bounds clip."""
    lo, hi = log_gain_bounds(config)
    logs = np.log10(np.maximum(np.asarray(gains, dtype=np.float64), 1e-300))
    return np.clip(2.0 * (logs - lo) / (hi - lo) - 1.0, -1.0, 1.0)


def slog(q: np.ndarray, q0: float, q_max: float) -> np.ndarray:
    """Signed log scaling to [-1, 1]: sign(q) ln(1 + |q|/q0) / ln(1 + q_max/q0), clipped."""
    return np.clip(np.sign(q) * np.log1p(np.abs(q) / q0) / math.log1p(q_max / q0), -1.0, 1.0)


# observation scales: (name, unit, q0, q_max) for the signed-log channels
OBS_SCALES = {
    "error": ("position error xd - x", "m", 1e-6, 5e-3),
    "velocity": ("piston velocity", "m/s", 1e-4, 5.0),
    "acceleration": ("piston acceleration (accelerometer)", "m/s^2", 1e-2, 1e5),
    "vibration": ("running RMS of band-limited (10-1000 Hz) velocity", "mm/s", 1e-2, 1e4),
}


class MillVibCore:
    """N episodes of the screw-down plant in one of two modes: 'gain' or 'valve'."""

    def __init__(self, n: int, mode: str, config: EnvConfig, *, residual: bool = False,
                 observe_params: bool | None = None, observe_phase: bool | None = None):
        if mode not in ("gain", "valve"):
            raise ValueError(f"mode = {mode!r} is invalid: 'gain' or 'valve'")
        if n < 1:
            raise ValueError(f"n = {n} environments is invalid: need >= 1")
        self.n, self.mode, self.cfg, self.residual = n, mode, config, bool(residual and mode == "valve")
        raw = config.raw
        self.observe_params = raw["observation"].get("params", False) if observe_params is None else observe_params
        self.observe_phase = raw["observation"].get("phase", False) if observe_phase is None else observe_phase
        self.period_s = config.decision_dt_s if mode == "gain" else config.control_dt_s
        self.n_sub = int(round(self.period_s / config.control_dt_s))
        self.spp = int(round(config.control_dt_s * config.sample_rate_hz))
        self.n_samp = self.n_sub * self.spp
        self.dt_sample = 1.0 / config.sample_rate_hz
        self.max_steps = int(round(config.episode_s / self.period_s))
        self.n_ctrl = self.max_steps * self.n_sub
        self.disturbances, self.noise, self.delay = build_disturbances(raw["disturbances"])

        acts = raw["actions"]
        self.gain_lo, self.gain_hi = log_gain_bounds(config)
        self.u_range = float(acts["residual_range_v"] if self.residual else acts["u_range_v"])
        self.residual_gains = PIDGains(*acts["residual_gains"])
        self.act_dim = 3 if mode == "gain" else 1
        self.action_space = spaces.Box(-1.0, 1.0, (self.act_dim,), dtype=np.float32)
        self.obs_names = self._obs_names()
        self.observation_space = spaces.Box(-1.0, 1.0, (len(self.obs_names),), dtype=np.float32)

        rew = raw["reward"]
        self.w_vib, self.w_trk, self.w_eff = rew["w_vibration"], rew["w_tracking"], rew["w_effort"]
        self.vib_scale = rew["vibration_scale_mm_s"] * 1e-3
        self.trk_scale = rew["tracking_scale_um"] * 1e-6
        self.penalty = rew["terminal_penalty"]
        self.ema_gain = 1.0 - math.exp(-self.period_s / rew["vib_time_constant_s"])
        env = raw["envelope"]
        self.x_max, self.p_min, self.p_max_factor = env["x_max_m"], env["p_min_pa"], env["p_max_factor"]
        self.sos = ssig.butter(2, (10.0, 1000.0), btype="bandpass", fs=config.sample_rate_hz, output="sos")

        # per-environment state
        self.np_random: list[np.random.Generator] = [seeding.np_random(None)[0] for _ in range(n)]
        self.noise_rng: list[np.random.Generator | None] = [None] * n
        self.params: list[MillParams] = [config.base_params] * n
        self.params_info: list[dict] = [{}] * n
        self.profiles: list[EpisodeProfile | None] = [None] * n
        self.scenario: list[str | None] = [None] * n
        self.P = np.zeros((n, NPACK))
        self.C = np.zeros((n, NC))
        self.Y = np.zeros((n, NY))
        self.F = np.zeros((n, NY))
        self.H = np.full(n, kernel.H_INIT)
        self.T = np.zeros(n)
        self.ATOL = np.zeros((n, NY))
        self.XD = np.zeros((n, self.n_ctrl + self.n_sub))
        self.DFL = np.zeros((n, self.n_ctrl + self.n_sub))
        self.k = np.zeros(n, dtype=np.int64)
        self.zi = np.zeros((self.sos.shape[0], n, 2))
        self.vib_ema = np.zeros(n)
        self.sq_err_sum = np.zeros(n)
        self.acc_trace = np.zeros((n, self.max_steps * self.n_samp + 1))  # + the sample at t = 0
        self.n_trace = np.zeros(n, dtype=np.int64)
        self.last_action = np.zeros((n, self.act_dim))
        self.gains = np.zeros((n, 3))
        self.ep_return = np.zeros(n)
        self.obs_buf = np.zeros((n, self.delay + 1, len(self.obs_names)), dtype=np.float32)
        self.YS = np.zeros((n, self.n_samp + 1, NY))
        self.AUXS = np.zeros((n, self.n_samp + 1, NAUX))
        self.status = np.zeros(n, dtype=np.int64)
        self.n_valid = np.zeros(n, dtype=np.int64)
        self.n_steps = np.zeros(n, dtype=np.int64)
        self.rtol = DEFAULT_RTOL_FAST
        self.max_kernel_steps = int(MAX_STEPS_PER_SECOND * self.period_s) + 1000
        self.history: list[dict] = [{}]

    # ------------------------------------------------------------------------------------------
    def _obs_names(self) -> list[str]:
        names = ["error", "velocity", "acceleration", "pressure", "vibration"]
        if self.mode == "gain":
            names += ["log_kp", "log_ki", "log_kd"]
        else:
            names += ["last_action"]
            if self.residual:
                names += ["pid_command"]
        if self.observe_phase:
            names += ["pump_sin", "pump_cos"]
        if self.observe_params:
            names += ["log_c1", "log_Ct"]
        return names

    def gains_from_action(self, action: np.ndarray) -> np.ndarray:
        """Map actions in [-1, 1]^3 to (KP, KI, KD) on a log scale within the configured bounds."""
        frac = (np.clip(action, -1.0, 1.0) + 1.0) / 2.0
        return 10.0 ** (self.gain_lo + frac * (self.gain_hi - self.gain_lo))

    def action_from_gains(self, gains: np.ndarray) -> np.ndarray:
        """Inverse of `gains_from_action` (gains outside the bounds are clipped)."""
        return action_from_gains(gains, self.cfg)

    # ------------------------------------------------------------------------------------------
    def seed_env(self, i: int, seed: int | None) -> None:
        self.np_random[i], _ = seeding.np_random(seed)

    def reset_env(self, i: int, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start a new episode in environment i (a new plant, disturbances, initial state)."""
        if seed is not None:
            self.seed_env(i, seed)
        options = dict(options or {})
        unknown = set(options) - {"params", "scenario", "x0"}
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}: use 'params', 'scenario' or 'x0'")
        episode_seed = int(self.np_random[i].integers(2**63 - 1))
        plant_ss, dist_ss, noise_ss = np.random.SeedSequence(episode_seed).spawn(3)
        plant_rng, dist_rng = np.random.default_rng(plant_ss), np.random.default_rng(dist_ss)
        self.noise_rng[i] = np.random.default_rng(noise_ss)

        pinned: dict[str, float] = {}
        x0 = self.cfg["initial"]["x0_m"]
        jitter = self.cfg["initial"].get("x0_jitter_m", 0.0) or 0.0
        scenario = options.get("scenario")
        self.scenario[i] = scenario
        disturb = self.disturbances
        if scenario is not None:
            from millvib_env.envs.scenarios import get_scenario

            sc = get_scenario(scenario)
            # a scenario is a fixed plant: Table 1 (the config's base plant) plus its own changes
            pinned.update({d.name: getattr(self.cfg.base_params, d.name) for d in self.cfg.randomize})
            pinned.update(sc.params)
            x0, jitter = sc.x0_m, 0.0
            if sc.quiet:
                disturb = []
        if options.get("params"):
            pinned.update({k: float(v) for k, v in options["params"].items()})
        draws = {d.name: d.sample(plant_rng) for d in self.cfg.randomize}  # always drawn: same stream
        draws.update(pinned)
        params = self.cfg.base_params.replace(**draws)
        if options.get("x0") is not None:
            x0, jitter = float(options["x0"]), 0.0
        x0 = x0 + (plant_rng.uniform(-jitter, jitter) if jitter else 0.0)

        profile = EpisodeProfile(self.n_ctrl, self.cfg.control_dt_s)
        for d in disturb:
            d.apply(dist_rng, profile, params)
        self.params[i] = params
        self.params_info[i] = {"c1": params.c1, "Ct": params.Ct, "beta_e": params.beta_e, "mt": params.mt,
                               "FL": params.FL, "pulse_amp": params.pulse_amp}
        self.profiles[i] = profile
        self.P[i] = pack(params)
        self.ATOL[i] = self.rtol * state_scale(params)
        self.Y[i] = initial_state(params, x0=x0)
        self.H[i] = kernel.H_INIT
        self.T[i] = 0.0
        self.XD[i, :self.n_ctrl] = profile.xd
        self.XD[i, self.n_ctrl:] = profile.xd[-1]
        self.DFL[i, :self.n_ctrl] = profile.dFL
        self.DFL[i, self.n_ctrl:] = profile.dFL[-1]
        if self.mode == "gain":
            start = PAPER_GAINS
            c = drive_vector(start)
            self.gains[i] = start.to_array()
        else:
            c = drive_vector(self.residual_gains, pid_on=self.residual)
            self.gains[i] = self.residual_gains.to_array() if self.residual else 0.0
        c[C_EA], c[C_EW], c[C_EP] = profile.ecc_amp_n, profile.ecc_omega, profile.ecc_phase
        self.C[i] = c
        self.k[i] = 0
        self.zi[:, i, :] = 0.0
        self.vib_ema[i] = 0.0
        self.sq_err_sum[i] = 0.0
        # the record starts at t = 0, as simulate()'s does (the paper's start is at rest: a = 0)
        self.acc_trace[i, 0] = rhs_vector(0.0, self.Y[i], self.P[i], self.C[i])[IV]
        self.n_trace[i] = 1
        self.last_action[i] = 0.0
        self.ep_return[i] = 0.0
        if i == 0:
            self.history[0] = {"t": [0.0], "x": [np.array([x0])], "v": [np.zeros(1)], "gains": [self.gains[0].copy()],
                               "u": [0.0]}
        obs = self._observe(np.array([i]), e=np.array([profile.xd[0] - x0]), v=np.zeros(1), a=np.zeros(1),
                            pL=np.array([self.Y[i, IPL]]), u_pid=np.zeros(1))
        self.obs_buf[i] = obs[0]
        info = {"params": dict(self.params_info[i]), "scenario": scenario,
                "disturbances": list(profile.events), "x0": x0}
        return self.obs_buf[i, 0].copy(), info

    # ------------------------------------------------------------------------------------------
    def check_actions(self, actions: Any) -> np.ndarray:
        a = np.asarray(actions, dtype=np.float64)
        if a.shape == (self.act_dim,) and self.n == 1:
            a = a[None, :]
        if a.shape != (self.n, self.act_dim):
            raise ValueError(f"action has shape {np.shape(actions)}; expected ({self.n}, {self.act_dim})"
                             + (f" or ({self.act_dim},)" if self.n == 1 else ""))
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action contains NaN or inf: {a.tolist()}; allowed range is [-1, 1]")
        return np.clip(a, -1.0, 1.0)  # finite actions outside the Box are clipped, as Box actions are

    def step(self, actions: Any):
        """Advance every environment by one agent period. Returns obs, reward, terminated, truncated, infos."""
        a = self.check_actions(actions)
        n = self.n
        if self.mode == "gain":
            self.gains = self.gains_from_action(a)
            self.C[:, C_KP], self.C[:, C_KI], self.C[:, C_KD] = self.gains.T
            effort = np.mean(np.abs(a - self.last_action), axis=1)
        else:
            self.C[:, C_UEXT] = a[:, 0] * self.u_range
            effort = a[:, 0] ** 2
        self.last_action = a

        cols = self.k[:, None] * self.n_sub + np.arange(self.n_sub)
        xd_step = np.take_along_axis(self.XD, cols, axis=1)
        dfl_step = np.take_along_axis(self.DFL, cols, axis=1)
        active = np.ones(n, dtype=np.bool_)
        p_max = 10.0 * float(self.P[:, P_PS].max())  # numerical guard only; the envelope below is physical
        kernel.advance_batch(self.P, self.C, self.Y, self.F, self.H, self.T, xd_step, dfl_step, active,
                             self.cfg.control_dt_s, self.spp, self.rtol, self.ATOL, p_max, self.max_kernel_steps,
                             self.YS, self.AUXS, self.status, self.n_valid, self.n_steps)

        samples = self.YS[:, 1:, :]
        aux = self.AUXS[:, 1:, :]
        failed = self.status != 0
        if failed.any():  # hold the last good sample so nothing non-finite reaches the filters
            valid = np.arange(1, self.n_samp + 1)[None, :] < self.n_valid[:, None]
            last = np.maximum(self.n_valid - 1, 0)
            for b in np.flatnonzero(failed):
                good_y = self.YS[b, last[b]] if np.all(np.isfinite(self.YS[b, last[b]])) else self.YS[b, 0]
                good_a = self.AUXS[b, last[b]] if np.all(np.isfinite(self.AUXS[b, last[b]])) else self.AUXS[b, 0]
                samples[b, ~valid[b]] = good_y
                aux[b, ~valid[b]] = good_a
                if not np.all(np.isfinite(self.Y[b])):
                    self.Y[b] = good_y
        x, v, pL = samples[:, :, IX], samples[:, :, IV], samples[:, :, IPL]
        acc, u = aux[:, :, A_ACC], aux[:, :, A_U]
        xd = np.repeat(xd_step, self.spp, axis=1)
        e = xd - x
        v_band, self.zi = ssig.sosfilt(self.sos, v, axis=1, zi=self.zi)
        vib_ms = np.mean(v_band**2, axis=1)
        err_ms = np.mean(e**2, axis=1)
        self.vib_ema += self.ema_gain * (vib_ms - self.vib_ema)
        rows = np.arange(n)[:, None]
        cols = self.n_trace[:, None] + np.arange(self.n_samp)[None, :]
        self.acc_trace[rows, cols] = acc
        self.n_trace += self.n_samp
        self.sq_err_sum += err_ms * self.n_samp

        ps = self.P[:, P_PS]
        terminated = failed | (np.abs(x).max(axis=1) > self.x_max) | (pL.min(axis=1) < self.p_min) \
            | (pL.max(axis=1) > self.p_max_factor * ps)
        self.k += 1
        truncated = (self.k >= self.max_steps) & ~terminated
        reward = -(self.w_vib * np.sqrt(vib_ms) / self.vib_scale + self.w_trk * np.sqrt(err_ms) / self.trk_scale
                   + self.w_eff * effort) - self.penalty * terminated
        self.ep_return += reward

        u_pid = u[:, -1] - self.C[:, C_UEXT] if self.residual else np.zeros(n)
        obs = self._observe(np.arange(n), e=e[:, -1], v=v[:, -1], a=acc[:, -1], pL=pL[:, -1], u_pid=u_pid)
        if self.delay:
            self.obs_buf[:, 1:] = self.obs_buf[:, :-1]
        self.obs_buf[:, 0] = obs
        out_obs = self.obs_buf[:, -1].copy()

        infos: list[dict] = []
        for i in range(n):
            info = {"params": dict(self.params_info[i])}
            if terminated[i] or truncated[i]:
                info.update(self.episode_metrics(i, bool(terminated[i])))
            infos.append(info)
        self._record_history(x, v, u)
        return out_obs, reward.astype(np.float64), terminated, truncated, infos

    def _observe(self, idx: np.ndarray, *, e, v, a, pL, u_pid) -> np.ndarray:
        if self.noise is not None:
            noise = np.stack([self.noise.sample(self.noise_rng[i], 1)[0] for i in idx])
            e, v, a = e - noise[:, 0], v + noise[:, 1], a + noise[:, 2]
        ps = self.P[idx, P_PS]
        cols = [slog(e, *OBS_SCALES["error"][2:]), slog(v, *OBS_SCALES["velocity"][2:]),
                slog(a, *OBS_SCALES["acceleration"][2:]), np.clip((pL - ps / 2) / ps, -1, 1),
                slog(np.sqrt(self.vib_ema[idx]) * 1e3, *OBS_SCALES["vibration"][2:])]
        if self.mode == "gain":
            cols += list(self.action_from_gains(self.gains[idx]).T)
        else:
            cols.append(self.last_action[idx, 0])
            if self.residual:
                cols.append(np.clip(u_pid / self.u_range, -1, 1))
        if self.observe_phase:
            phase = 2 * np.pi * self.P[idx, P_PF] * self.T[idx]
            cols += [np.sin(phase), np.cos(phase)]
        if self.observe_params:
            for name, (lo, hi) in PARAM_OBS_RANGES.items():
                vals = np.log([getattr(self.params[i], name) for i in idx])
                cols.append(np.clip(2 * (vals - math.log(lo)) / (math.log(hi) - math.log(lo)) - 1, -1, 1))
        return np.stack(cols, axis=1).astype(np.float32)

    def episode_metrics(self, i: int, terminated: bool) -> dict:
        """Episode-end metrics of environment i (severity over the whole episode, by vibration_severity)."""
        n_tr = int(self.n_trace[i])
        acc = self.acc_trace[i, :n_tr]
        sev = vibration_severity(acc, self.cfg.sample_rate_hz) if n_tr >= 64 else float("inf")
        if not math.isfinite(sev):
            sev = float("inf")
        trk = math.sqrt(self.sq_err_sum[i] / max(n_tr, 1))
        return {"severity": sev, "tracking_rms_um": trk * 1e6,
                "iso_zone": iso_zone(sev) if math.isfinite(sev) else "D",
                "diverged": bool(terminated), "episode_return": float(self.ep_return[i]),
                "episode_steps": int(self.k[i]), "scenario": self.scenario[i]}

    def _record_history(self, x, v, u) -> None:
        """Keep the first environment's recent samples for rendering."""
        h = self.history[0]
        h["t"].append(self.T[0])
        h["x"].append(x[0].copy())
        h["v"].append(v[0].copy())
        h["gains"].append(self.gains[0].copy())
        h["u"].append(float(u[0, -1]))
        keep = max(2, int(RENDER_WINDOW_S / self.period_s) + 1)
        for key in h:
            del h[key][:-keep]
