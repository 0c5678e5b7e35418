"""Observation-normalisation statistics in a data format: an .npz that loading cannot run code from.

SB3 saves `VecNormalize` by pickling the whole wrapper, and unpickling a file can run arbitrary
code. An agent's statistics are written here as plain arrays (mean, var, count, clip, epsilon) and
read with ``np.load(allow_pickle=False)``. The pickle is still written beside a training run, for
SB3's own `VecNormalize.load` when a run is resumed from a checkpoint (a trusted, local file).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from millvib_env._checks import shown, shown_path
from millvib_env._paths import atomic_path

__all__ = ["ObsStats", "save_obs_stats", "load_obs_stats", "STATS_FILE", "normalize_kwargs", "normalizes_obs"]

#: the keywords of SB3's `VecNormalize` a hyperparameter file's ``normalize`` may set
VECNORMALIZE_KEYS = ("norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon")

STATS_FILE = "vecnormalize.npz"
#: rows a large batch is normalised at a time (`ObsStats.normalize`)
_ROWS = 8192


@dataclass(frozen=True)
class ObsStats:
    mean: np.ndarray
    var: np.ndarray
    count: float
    clip_obs: float
    epsilon: float

    def normalize(self, obs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """VecNormalize's observation transform, as float32. A large batch (a distillation's pooled samples) is
        transformed `_ROWS` rows at a time into the output: the same operations on every element, so the same
        numbers, without the whole batch's float64 temporaries (twenty times faster on a distillation's pool:
        docs/performance.md). `out`: a float32 array of the batch's shape to write into (a distillation reuses
        one for its pool), returned."""
        obs = np.asarray(obs)
        scale = np.sqrt(self.var + self.epsilon)
        if out is None and (obs.ndim < 2 or obs.shape[0] <= _ROWS):
            return np.clip((obs - self.mean) / scale, -self.clip_obs, self.clip_obs).astype(np.float32)
        if out is None:
            out = np.empty(obs.shape, dtype=np.float32)
        elif out.shape != obs.shape or out.dtype != np.float32:
            raise ValueError(f"out is invalid: a float32 array of shape {obs.shape}, not {out.dtype} {out.shape}")
        for i in range(0, obs.shape[0], _ROWS):
            out[i:i + _ROWS] = np.clip((obs[i:i + _ROWS] - self.mean) / scale, -self.clip_obs, self.clip_obs)
        return out


def normalize_kwargs(value, where: str = "normalize") -> dict | None:
    """Every form of the zoo's ``normalize`` as SB3's `VecNormalize` keywords, None for no normalisation:
    ``true`` / ``false`` / None, the strings ``"True"``, ``"False"``, ``"None"``, a dict, or the zoo's dict string
    (``"dict(norm_obs=True, norm_reward=False)"``, ``"{'norm_obs': True}"``, read as data, never run). ``true``
    is SB3's defaults (observations and rewards normalised). ValueError naming `where` for anything else, so a
    file is refused before its first training step, never after it."""
    import ast

    text = value.strip() if isinstance(value, str) else None
    if value is None or value is False or text in ("None", "False", "false", ""):
        return None
    if value is True or text in ("True", "true"):
        return {"norm_obs": True, "norm_reward": True}
    if text is not None and text.startswith(("dict(", "{")):
        try:
            tree = ast.parse(text, mode="eval").body
            if isinstance(tree, ast.Call) and isinstance(tree.func, ast.Name) and tree.func.id == "dict" \
                    and not tree.args:
                value = {kw.arg: ast.literal_eval(kw.value) for kw in tree.keywords}
            else:
                value = ast.literal_eval(tree)
        except (SyntaxError, ValueError):
            value = text
    if not isinstance(value, dict) or any(k not in VECNORMALIZE_KEYS for k in value):
        raise ValueError(f"{where} = {shown(value)} is invalid: true, false, None, or VecNormalize's keywords "
                         f"({', '.join(VECNORMALIZE_KEYS)}) as a dict or the zoo's \"dict(norm_obs=True, ...)\"")
    bools = {k: value[k] for k in ("norm_obs", "norm_reward") if k in value}
    nums = {k: value[k] for k in value if k not in bools}
    if any(not isinstance(v, bool) for v in bools.values()) or any(
            isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0
            for v in nums.values()):
        raise ValueError(f"{where} = {shown(value)} is invalid: norm_obs and norm_reward are true or false, "
                         "clip_obs, clip_reward, gamma and epsilon numbers > 0")
    return {"norm_obs": True, "norm_reward": True, **value}


def normalizes_obs(card_value, where: str = "normalize") -> bool:
    """Whether a card's ``normalize`` normalises the observations: the text `train` and `distill` write, "None"
    (or an early card's "False", "" or "{}") for none, or VecNormalize's keywords as a dict's text; ValueError
    naming `where` for anything else (a card is a record of what ran, not a form to interpret)."""
    text = card_value.strip() if isinstance(card_value, str) else None
    if text in ("None", "False", "", "{}"):
        return False
    if text is None or not text.startswith(("{", "dict(")):
        raise ValueError(f"{where} = {shown(card_value)} is invalid: 'None' or the VecNormalize arguments as train "
                         "writes them (e.g. \"{'norm_obs': True, 'norm_reward': True}\")")
    kw = normalize_kwargs(card_value, where)
    return kw is not None and bool(kw.get("norm_obs", True))


def save_obs_stats(venv, path: str | Path) -> Path:
    """Write the observation statistics of a `VecNormalize` (atomically)."""
    rms = venv.obs_rms
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, mean=rms.mean, var=rms.var, count=np.float64(rms.count),
                     clip_obs=np.float64(venv.clip_obs), epsilon=np.float64(venv.epsilon))
    return Path(path)


def load_obs_stats(path: str | Path, obs_dim: int | None = None) -> ObsStats:
    """Read statistics written by `save_obs_stats`; ValueError naming the file if it is missing,
    unreadable or does not match `obs_dim` observations."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{shown_path(path)} is missing: the agent's observation statistics are needed to run it "
                         "(without them it would run on unnormalised observations and act wrongly)")
    try:
        with np.load(path, allow_pickle=False) as data:
            raw = {k: np.asarray(data[k]) for k in ("mean", "var", "count", "clip_obs", "epsilon")}
    except Exception as err:
        raise ValueError(f"{shown_path(path)} is not a valid statistics file: {type(err).__name__}: {err}") from None
    for key, array in raw.items():  # a complex or text value would be cast (its imaginary part dropped) or fail later
        if array.dtype.kind not in "biuf":
            raise ValueError(f"{shown_path(path)}: {key} has dtype {array.dtype}; allowed: real numbers")
    try:
        stats = ObsStats(raw["mean"].astype(float), raw["var"].astype(float), float(raw["count"]),
                         float(raw["clip_obs"]), float(raw["epsilon"]))
    except (TypeError, ValueError) as err:
        raise ValueError(f"{shown_path(path)} is not a valid statistics file: {type(err).__name__}: {err}") from None
    if stats.mean.ndim != 1 or stats.mean.shape != stats.var.shape or not np.all(np.isfinite(stats.mean)) \
            or not np.all(np.isfinite(stats.var)) or np.any(stats.var < 0):
        raise ValueError(f"{shown_path(path)}: mean and var must be finite vectors of one length, var >= 0")
    for name, value in (("clip_obs", stats.clip_obs), ("epsilon", stats.epsilon)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{shown_path(path)}: {name} = {shown(value)} is invalid: must be finite and > 0 "
                             "(VecNormalize's clip_obs and epsilon)")
    if not (math.isfinite(stats.count) and stats.count >= 0):
        raise ValueError(f"{shown_path(path)}: count = {shown(stats.count)} is invalid: must be finite and >= 0")
    if obs_dim is not None and stats.mean.size != obs_dim:
        raise ValueError(f"{shown_path(path)} holds statistics of {stats.mean.size} observations; the agent's "
                         f"environment has {obs_dim}")
    return stats
