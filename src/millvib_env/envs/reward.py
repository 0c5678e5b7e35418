"""The per-step reward and the running vibration measure the agent observes.

``r = -(w_v RMS(v_b) / vibration_scale + w_e RMS(e) / tracking_scale + w_u effort + w_o offset)
- (P + P_s n_left) [terminated]``
with v_b the band-limited (10-1000 Hz, causal 4th-order Butterworth) piston velocity and
e = xd - x, both over the period's plant samples (their mean squares come from `envs.period`, which
runs the filter with the sections designed here); effort is the mean |change of the gain action|
(gain mode) or the squared valve action (valve mode); offset (gain mode, ``w_offset``, default 0) is
the mean squared action: with a relative action, how far the gains are from their base controller.
P (``terminal_penalty``) is paid once when an episode leaves its envelope, and P_s
(``terminal_per_step``, v1: `DIVERGED_COST`) for each of the n_left steps it did not run, so an
episode that fails early never earns more than one that runs to its end at that cost per step.

A user's own reward is any callable ``reward(terms) -> rewards`` (`RewardFunction`), given to an environment as
``reward_fn=``: it gets the period's terms (`RewardTerms`, the config's reward among them) and returns one
finite reward per environment, which the env returns in its place. The observation's running vibration measure
is the config's either way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from millvib_env._checks import callable_or_none, shown
from millvib_env.envs.config import RewardSettings
from millvib_env.envs.filter_design import butter_sos
from millvib_env.severity import severity_band

__all__ = ["Reward", "RewardTerms", "RewardFunction", "EpisodeCostReward", "DIVERGED_COST"]


@dataclass(frozen=True)
class RewardTerms:
    """One agent period's terms, one value per environment (arrays of shape (n,))."""

    vibration_rms_m_s: np.ndarray  # RMS of the band-limited (severity band) piston velocity over the period (m/s)
    tracking_rms_m: np.ndarray     # RMS of the position error xd - x over the period (m)
    effort: np.ndarray             # mean |change of the gain action| (gain mode) or squared valve action (valve)
    offset: np.ndarray             # mean squared gain action (gain mode; zeros in valve mode)
    terminated: np.ndarray         # the episode left its envelope (or its integration failed) in this period
    steps_left: np.ndarray         # the agent steps the episode had left after this one
    config_reward: np.ndarray      # the config's reward for the period (what the env returns without reward_fn)


class RewardFunction(Protocol):
    """A user's reward (``reward_fn=`` of every environment): the period's terms -> one finite reward per env."""

    def __call__(self, terms: RewardTerms) -> Any: ...


def user_reward(fn: Any) -> RewardFunction | None:
    """An environment's ``reward_fn``, checked: None or a callable."""
    return callable_or_none("reward_fn", fn, "a callable reward(terms) -> one reward per environment "
                                             "(envs.reward.RewardFunction)")

class EpisodeCostReward:
    """A reward (``reward_fn=``) that scores each period by what it adds to the episode's cost, not by its own RMS.

    The benchmark's cost is an episode's RMS: ``sqrt(mean_t ms_t) / scale`` of the band-limited velocity and of the
    position error (ms_t: a period's mean square). The config's reward sums each period's own RMS, ``sqrt(ms_t) /
    scale``, whose sum is not the cost (Jensen) and whose slope ``1 / (2 sqrt(ms_t))`` is largest in the quietest
    periods: an agent that follows it trades loud periods for quiet ones, where the cost does the opposite. This
    reward is ``-ms_t / (sqrt(M_t) scale)`` for each of the two, M_t the episode's running mean square so far (this
    period's included): the cost's own slope at the episode's level as far as it is known, the same value as the
    config's reward on a steady signal. The config's other terms (effort, offset, the penalty of leaving the
    envelope) are kept. `vibration_scale_mm_s`, `tracking_scale_um`: the cost's scales (the config's reward's);
    `w_vibration`, `w_tracking`: the config's weights, whose terms this replaces. One instance per environment
    batch: it keeps each environment's running sums, restarted after a period that ends an episode."""

    def __init__(self, vibration_scale_mm_s: float = 4.5, tracking_scale_um: float = 10.0,
                 w_vibration: float = 1.0, w_tracking: float = 1.0):
        self.scales = (vibration_scale_mm_s * 1e-3, tracking_scale_um * 1e-6)
        self.weights = (w_vibration, w_tracking)
        self.sums: np.ndarray | None = None
        self.count: np.ndarray | None = None

    def follow(self, reward: "Reward") -> "EpisodeCostReward":
        """Take the scales and weights of an environment's config reward (`Reward`: its ``core.reward``)."""
        self.scales = (reward.vib_scale, reward.trk_scale)
        self.weights = (reward.w_vib, reward.w_trk)
        return self

    def __call__(self, terms: RewardTerms) -> np.ndarray:
        ms = np.stack([terms.vibration_rms_m_s ** 2, terms.tracking_rms_m ** 2], axis=1)
        if self.sums is None or self.sums.shape != ms.shape:
            self.sums, self.count = np.zeros_like(ms), np.zeros(ms.shape[0])
        assert self.count is not None
        self.sums += ms
        self.count += 1
        level = np.sqrt(np.maximum(self.sums / self.count[:, None], 1e-300))
        scales, weights = np.array(self.scales), np.array(self.weights)
        own = np.sqrt(ms) / scales  # the config's terms this replaces
        marginal = ms / level / scales
        reward = terms.config_reward + (weights * (own - marginal)).sum(axis=1)
        ended = terms.terminated | (terms.steps_left <= 0)
        self.sums[ended], self.count[ended] = 0.0, 0.0
        return reward


#: what an episode that leaves its envelope (or whose integration fails) costs at least, in the
#: benchmark's cost units (severity / 4.5 mm/s + tracking RMS / 10 um): twice the tracking cost of
#: holding the envelope's edge (5 mm) for a whole episode, so no episode that runs to its end inside the
#: envelope at a plausible severity costs as much. The benchmark and every tuner score a diverged
#: episode at max(its cost, this); the v1 reward charges it per step not run.
DIVERGED_COST = 1000.0


class Reward:
    """Reward weights and the band-pass filter state of a batch of environments."""

    def __init__(self, spec: RewardSettings, *, period_s: float, sample_rate_hz: float, n: int,
                 user: RewardFunction | None = None):
        #: a user's reward (``reward_fn``), returned in place of the config's
        self.user = user_reward(user)
        self.w_vib, self.w_trk, self.w_eff = spec.w_vibration, spec.w_tracking, spec.w_effort
        self.w_off = float(spec.w_offset)
        self.vib_scale = spec.vibration_scale_mm_s * 1e-3
        self.trk_scale = spec.tracking_scale_um * 1e-6
        self.penalty = spec.terminal_penalty
        self.penalty_per_step = float(spec.terminal_per_step)
        self.ema_gain = 1.0 - math.exp(-period_s / spec.vib_time_constant_s)
        self.sos = butter_sos(2, severity_band(), "bandpass", sample_rate_hz)
        #: the filter's section states, per environment (n, sections, 2)
        self.zi = np.zeros((n, self.sos.shape[0], 2))
        self.vib_ema = np.zeros(n)

    def start(self, i: int) -> None:
        self.zi[i] = 0.0
        self.vib_ema[i] = 0.0

    def step(self, vib_ms: np.ndarray, err_ms: np.ndarray, effort: np.ndarray, terminated: np.ndarray,
             offset: np.ndarray | None = None, remaining: np.ndarray | None = None) -> np.ndarray:
        """This period's reward per env, from the mean squares of its band-passed velocity and of its
        position error (`envs.period.summarize_period`, which also advances `zi`)."""
        self.vib_ema += self.ema_gain * (vib_ms - self.vib_ema)
        reward = -(self.w_vib * np.sqrt(vib_ms) / self.vib_scale + self.w_trk * np.sqrt(err_ms) / self.trk_scale
                   + self.w_eff * effort) - self.penalty * terminated
        if self.w_off and offset is not None:
            reward = reward - self.w_off * offset
        if self.penalty_per_step and remaining is not None:
            reward = reward - self.penalty_per_step * np.maximum(remaining, 0) * terminated
        if self.user is not None:
            reward = self._users(vib_ms, err_ms, effort, terminated, offset, remaining, reward)
        return reward

    def _users(self, vib_ms, err_ms, effort, terminated, offset, remaining, reward) -> np.ndarray:
        n = reward.shape[0]
        terms = RewardTerms(np.sqrt(vib_ms), np.sqrt(err_ms), np.asarray(effort, float),
                            np.zeros(n) if offset is None else offset, np.asarray(terminated, bool),
                            np.zeros(n, int) if remaining is None else np.maximum(remaining, 0), reward.copy())
        assert self.user is not None
        out = self.user(terms)
        try:
            values = np.broadcast_to(np.asarray(out, dtype=np.float64), (n,)).copy()
        except (TypeError, ValueError, OverflowError):
            values = np.full(n, np.nan)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"reward_fn {shown(self.user)} returned {shown(out)}: one finite reward per environment "
                             f"({n}) is needed")
        return values

    @property
    def vib_rms(self) -> np.ndarray:
        """Running RMS of the band-limited velocity (m/s), time constant vib_time_constant_s."""
        return np.sqrt(self.vib_ema)
