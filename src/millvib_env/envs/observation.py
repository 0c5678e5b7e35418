"""What the agent sees: the observation channels, their scaling and the sensor noise and delay.

Signed-log channels are ``sign(q) ln(1 + |q|/q0) / ln(1 + q_max/q0)``, clipped to [-1, 1], so
micrometre errors and millimetre transients both stay visible.
"""

from __future__ import annotations

import math

import numpy as np

from millvib_env.params import studied_range

__all__ = ["slog", "unslog", "OBS_SCALES", "PARAM_OBS_RANGES", "HISTORY_CHANNELS", "Observer"]

#: with observe_params, log c1 and log Ct are mapped linearly from these ranges to [-1, 1]
PARAM_OBS_RANGES = {"c1": studied_range("c1"), "Ct": studied_range("Ct")}

#: the channels a history (`ObservationSettings.history_samples`) repeats: what the loop's sensors measured and
#: what the controller itself sent, never the preview, the phase or the true parameters
HISTORY_CHANNELS = ("error", "velocity", "acceleration", "pressure", "last_action", "pid_command", "load_force")

# observation scales: (name, unit, q0, q_max) for the signed-log channels
OBS_SCALES = {
    "error": ("position error xd - x", "m", 1e-6, 5e-3),
    "velocity": ("piston velocity", "m/s", 1e-4, 5.0),
    "acceleration": ("piston acceleration (accelerometer)", "m/s^2", 1e-2, 1e5),
    "vibration": ("running RMS of band-limited (10-1000 Hz) velocity", "mm/s", 1e-2, 1e4),
    "load_force": ("load cells' rolling-force deviation FL(t) - FL", "N", 1e3, 1e6),
}


def slog(q: np.ndarray, q0: float, q_max: float) -> np.ndarray:
    """Signed log scaling to [-1, 1]: sign(q) ln(1 + |q|/q0) / ln(1 + q_max/q0), clipped."""
    return _slog(q, q0, math.log1p(q_max / q0))


def unslog(y: np.ndarray, scale: str) -> np.ndarray:
    """The inverse of `slog` for the channel scale `scale` (an `OBS_SCALES` key), inside the clipping: what a
    controller that reads a signed-log channel (`control.preview`) recovers in the channel's unit."""
    q0, q_max = OBS_SCALES[scale][2:]
    return np.sign(y) * q0 * np.expm1(np.abs(y) * math.log1p(q_max / q0))


def _slog(q: np.ndarray, q0, denom) -> np.ndarray:
    """`slog` with its denominator ln(1 + q_max/q0) given; q0 and denom may be columns, one per row of q
    (several channels scaled in one set of numpy calls, the same arithmetic as one call per channel)."""
    return _clip1(np.sign(q) * np.log1p(np.abs(q) / q0) / denom)


def _clip1(q: np.ndarray) -> np.ndarray:
    """`q` clipped to [-1, 1]: np.clip's numbers (NaN stays NaN) without its wrappers' cost per call."""
    return np.minimum(np.maximum(q, -1.0), 1.0)


#: the channels built together (`Observer.build`), and their q0 and ln(1 + q_max/q0) as columns
_ROW_CHANNELS = ("error", "velocity", "acceleration", "vibration")
_ROW_Q0 = np.array([[OBS_SCALES[k][2]] for k in _ROW_CHANNELS])
_ROW_DENOM = np.array([[math.log1p(OBS_SCALES[k][3] / OBS_SCALES[k][2])] for k in _ROW_CHANNELS])


class Observer:
    """Builds the observation vectors of a batch of environments in one mode."""

    def __init__(self, mode: str, *, residual: bool, gain_names: tuple[str, ...], observe_phase: bool,
                 observe_params: bool, noise, delay: int, n: int, observe_force: bool = False,
                 preview_samples: tuple = (), history_samples: tuple = (), history_filters: tuple = ()):
        self.mode, self.residual, self.noise, self.delay = mode, residual, noise, delay
        self.observe_phase, self.observe_params, self.observe_force = observe_phase, observe_params, observe_force
        names = ["error", "velocity", "acceleration", "pressure", "vibration"]
        if mode == "gain":
            names += [f"log_{g}" for g in gain_names]
        else:
            names += ["last_action"] + (["pid_command"] if residual else [])
        if observe_phase:
            names += ["pump_sin", "pump_cos"]
        if observe_params:
            names += ["log_c1", "log_Ct"]
        if observe_force:
            names += ["load_force"]
        self.preview_samples = tuple(preview_samples)
        names += [f"preview_force_{k}" for k in self.preview_samples]
        names += [f"preview_setpoint_{k}" for k in self.preview_samples]
        # a history: the measured channels as they were k agent steps ago, for each k (the newest first)
        self.history_samples = tuple(history_samples)
        self._hist_cols = np.array([j for j, nm in enumerate(names) if nm in HISTORY_CHANNELS], dtype=np.intp)
        self._n_now = len(names)
        names += [f"{names[j]}_lag_{k}" for k in self.history_samples for j in self._hist_cols]
        # a memory: the measured channels' moving averages and those of their squares, per time constant
        self.history_filters = tuple(history_filters)
        self._n_lagged = len(names)
        names += [f"{names[j]}_{what}_{tau}" for what in ("mean", "meansq") for tau in self.history_filters
                  for j in self._hist_cols]
        self._rate = np.array([1.0 / tau for tau in self.history_filters], dtype=np.float32)[None, :, None]
        self._mean = np.zeros((n, len(self.history_filters), len(self._hist_cols)), dtype=np.float32)
        self._meansq = np.zeros_like(self._mean)
        self.names = names
        self.buffer = np.zeros((n, delay + 1, len(names)), dtype=np.float32)
        # the sensor noise of each environment's episode, drawn ahead at its start (`start_noise`)
        self._noise_rng: list = [None] * n
        self._noise_z = np.zeros((n, 0, 3))
        self._noise_used = np.zeros(n, dtype=np.int64)
        self._noise_scale = None if noise is None else np.array([noise.x_m, noise.v_m_s, noise.a_m_s2])
        depth = max(self.history_samples) + 1 if self.history_samples else 0
        self._hist = np.zeros((n, depth, len(self._hist_cols)), dtype=np.float32)
        self._lags = np.array(self.history_samples, dtype=np.intp)

    def start_noise(self, i: int, rng: np.random.Generator, rows: int) -> None:
        """A new episode in environment i: its sensor noise comes from the episode's own stream `rng`, one
        standard normal triple per observation. The first `rows` triples are drawn now in one call: the same
        numbers in the same order as one draw per observation (numpy's generators fill an array draw by draw);
        an observation past them draws its own from `rng`, which goes on where the block ended."""
        if self._noise_scale is None:
            return
        if self._noise_z.shape[1] != rows:
            self._noise_z = np.zeros((len(self._noise_rng), rows, 3))
        self._noise_z[i] = rng.standard_normal((rows, 3))
        self._noise_rng[i] = rng
        self._noise_used[i] = 0

    def _noise(self, idx: np.ndarray) -> np.ndarray:
        """The next sensor noise of environments `idx` (m, m/s, m/s^2), one row each."""
        used = self._noise_used[idx]
        rows = self._noise_z.shape[1]
        z = self._noise_z[idx, np.minimum(used, rows - 1)]
        past = used >= rows
        if past.any():
            for j in np.flatnonzero(past):  # past the block: straight from the stream
                z[j] = self._noise_rng[idx[j]].standard_normal(3)
        self._noise_used[idx] = used + 1
        return z * self._noise_scale

    def build(self, idx: np.ndarray, *, e, v, a, pL, ps, vib_rms, control, u_pid, phase,
              params, force=None, preview=None) -> np.ndarray:
        """Observation rows for environments `idx` (sensor noise applied to e, v, a; each environment's noise
        was started by `start_noise`).

        control: the gain-action channels (gain mode) or the last action (valve mode); phase: the
        pump's phase angle (rad); params: (c1, Ct) pairs of the current plants; force: the load
        cells' force deviation (N); preview: (force change (N), set-point change (m)) to each look-ahead,
        two arrays of shape (len(idx), len(preview_samples)).
        """
        if self.noise is not None:
            noise = self._noise(np.asarray(idx))
            e, v, a = e - noise[:, 0], v + noise[:, 1], a + noise[:, 2]
        err, vel, acc, vib = _slog(np.array([e, v, a, vib_rms * 1e3]), _ROW_Q0, _ROW_DENOM)  # _ROW_CHANNELS
        cols = [err, vel, acc, _clip1((pL - ps / 2) / ps), vib]
        cols += list(np.atleast_2d(control).T) if self.mode == "gain" else [control]
        if self.mode == "valve" and self.residual:
            cols.append(_clip1(u_pid))
        if self.observe_phase:
            cols += [np.sin(phase), np.cos(phase)]
        if self.observe_params:
            for k, (lo, hi) in enumerate(PARAM_OBS_RANGES.values()):
                vals = np.log(np.asarray(params)[:, k])
                cols.append(np.clip(2 * (vals - math.log(lo)) / (math.log(hi) - math.log(lo)) - 1, -1, 1))
        if self.observe_force:
            cols.append(slog(np.asarray(force, float), *OBS_SCALES["load_force"][2:]))
        if self.preview_samples:
            df, dxd = preview
            cols += list(slog(np.asarray(df, float), *OBS_SCALES["load_force"][2:]).T)
            cols += list(slog(np.asarray(dxd, float), *OBS_SCALES["error"][2:]).T)
        rows = np.array(cols, dtype=np.float64).T.astype(np.float32, order="C")  # (environments, channels)
        if self.history_samples or self.history_filters:  # filled by start / push, which see every step
            rows = np.concatenate([rows, np.zeros((len(rows), len(self.names) - self._n_now), np.float32)], axis=1)
        return rows

    def start(self, i: int, obs: np.ndarray) -> np.ndarray:
        """A new episode in environment i: the delay line and the history hold its first observation."""
        if self.history_samples:
            self._hist[i] = obs[self._hist_cols]
            obs = obs.copy()
            obs[self._n_now:self._n_lagged] = self._hist[i, self._lags].reshape(-1)
        if self.history_filters:
            now = obs[self._hist_cols]
            self._mean[i], self._meansq[i] = now, now * now
            obs = obs.copy()
            obs[self._n_lagged:] = np.concatenate([self._mean[i].reshape(-1), self._meansq[i].reshape(-1)])
        self.buffer[i] = obs
        return self.buffer[i, 0].copy()

    def push(self, obs: np.ndarray) -> np.ndarray:
        """Append this step's observations of every environment; return what the agent sees."""
        if self.history_samples:
            self._hist[:, 1:] = self._hist[:, :-1]
            self._hist[:, 0] = obs[:, self._hist_cols]
            obs = obs.copy()
            obs[:, self._n_now:self._n_lagged] = self._hist[:, self._lags].reshape(len(obs), -1)
        if self.history_filters:
            now = obs[:, None, self._hist_cols]
            self._mean += self._rate * (now - self._mean)
            self._meansq += self._rate * (now * now - self._meansq)
            obs = obs.copy()
            m = len(obs)
            obs[:, self._n_lagged:] = np.concatenate([self._mean.reshape(m, -1), self._meansq.reshape(m, -1)], axis=1)
        if self.delay:
            self.buffer[:, 1:] = self.buffer[:, :-1]
        self.buffer[:, 0] = obs
        return self.buffer[:, -1].copy()
