"""The declared reads of the episodes under way: what code outside envs/ reads of `envs.core.MillVibCore`.

Controllers that read the plant (the MPC oracles, as controllers and as teachers), the evaluation's traces and the
distillation's labels read the episodes through these methods only, never the engine's arrays (a test holds it):
each returns a copy or a value computed from them, so a reader can neither change an episode nor depend on how
the engine lays out its state."""

from __future__ import annotations

from typing import Any

import numpy as np

from millvib_env.envs.core_settings import CoreSettings
from millvib_env.loop.kernel import K_UCTRL
from millvib_env.plant.model import A_ACC, A_U, C_EA, C_EP, C_EW, IV, IX

__all__ = ["EpisodeReads"]


class EpisodeReads:
    """The read interface `MillVibCore` gives its readers (module docstring). `idx` and `rows`: an environment or
    an array of them (numpy's indexing); `cols`: control samples of the episode's courses."""

    # the engine's arrays these reads are made from (`MillVibCore._allocate_state` makes them)
    Y: np.ndarray
    C: np.ndarray
    T: np.ndarray
    k: np.ndarray
    P: np.ndarray
    XD: np.ndarray
    DFL: np.ndarray
    GF: np.ndarray | None
    CS: np.ndarray
    YS: np.ndarray
    AUXS: np.ndarray
    u_ff: np.ndarray
    profiles: list
    #: the batch's fixed settings (its clock among them: `envs.core_settings`)
    settings: CoreSettings

    def _eccentricity(self, idx: Any, t: Any) -> np.ndarray:
        """The roll eccentricity's force (N) at times t, as `plant_rhs` applies it."""
        return self.C[idx, C_EA] * np.sin(self.C[idx, C_EW] * t + self.C[idx, C_EP])

    def plant_state(self, idx: Any) -> np.ndarray:
        """The plant's state now (`plant.model`'s states, in its order) of environments `idx`."""
        return np.array(self.Y[idx])

    def time_now(self, idx: Any) -> np.ndarray:
        """The plant's time now (s) of environments `idx`."""
        return np.array(self.T[idx])

    def steps_taken(self, i: int) -> int:
        """The agent steps environment i's episode has taken."""
        return int(self.k[i])

    def control_sample(self, idx: Any) -> np.ndarray:
        """The control sample each of environments `idx` is at: its column in the episode's courses."""
        return self.k[idx] * self.settings.n_sub

    @property
    def course_samples(self) -> int:
        """The control samples of an episode's courses (set-point, force steps): one period past its end."""
        return int(self.XD.shape[1])

    def setpoint_course(self, rows: Any, cols: Any) -> np.ndarray:
        """The set-point (m) of environments `rows` at control samples `cols` (the pass schedule's course)."""
        return np.array(self.XD[rows, cols])

    def force_course(self, rows: Any, cols: Any, t: Any) -> np.ndarray:
        """The rolling force's deviation (N) of environments `rows`: its steps at control samples `cols` and the
        rolls' eccentricity at times `t` (s), as `plant_rhs` applies them."""
        return self.DFL[rows, cols] + self._eccentricity(rows, t)

    def gauge_force_course(self, rows: Any, cols: Any, t: Any) -> np.ndarray:
        """`force_course` with the force steps as the episode's measured preview predicts them (`envs.gauge`: its
        timing, model and noise errors) instead of the plant's own; a clear error where the preview is exact."""
        if self.GF is None:
            raise ValueError("the force steps as the gauge predicts them need a measured preview: "
                             "observation.preview_samples and observation.preview_gauge: measured")
        return self.GF[rows, cols] + self._eccentricity(rows, t)

    def plant_packs(self, idx: Any) -> np.ndarray:
        """The packed plant parameters (`plant.model.pack_params`: the pump's ripple among them) of environments
        `idx`, one row each."""
        return np.array(self.P[idx])

    def plant_moves(self, i: int) -> bool:
        """Whether environment i's plant moves within its episode (a plant change: `current_params` follows it)."""
        profile = self.profiles[i]
        return profile is not None and profile.change is not None

    def controller_state(self, idx: Any, which: int) -> np.ndarray:
        """Entry `which` (`loop.kernel.CS_NAMES`) of the digital controllers' states of environments `idx`."""
        return np.array(self.CS[idx, which])

    def loop_command(self) -> np.ndarray:
        """Every environment's command (V) from the loop's own controller at the sample just taken, with the fixed
        feedforward under a residual action (`actions.residual_feedforward`; zero without one)."""
        return self.CS[:, K_UCTRL] + self.u_ff

    def period_setpoint(self, i: int) -> np.ndarray:
        """Environment i's set-point over the period about to run, at the plant's samples (call it before `step`)."""
        st = self.settings
        return np.repeat(self.XD[i, self.k[i] * st.n_sub + np.arange(st.n_sub)], st.spp)

    def period_trace(self, i: int) -> dict[str, np.ndarray]:
        """Environment i's samples of the period just integrated: position "x" (m), velocity "v" (m/s),
        acceleration "a" (m/s^2) and valve command "u" (V)."""
        n = self.settings.n_samp
        return {"x": self.YS[i, 1:n + 1, IX].copy(), "v": self.YS[i, 1:n + 1, IV].copy(),
                "a": self.AUXS[i, 1:n + 1, A_ACC].copy(), "u": self.AUXS[i, 1:n + 1, A_U].copy()}
