"""The callbacks of `millvib train`: evaluations on fixed plants (continued by a resumed run) and the critic's
warm-up under a held actor."""

from __future__ import annotations

from pathlib import Path
from typing import cast

import numpy as np

from millvib_env._checks import integer
from millvib_env.catalog.manifest import EVAL_CURVE
from millvib_env.catalog.normalization import STATS_FILE, save_obs_stats

__all__ = ["evaluation", "warmup"]


def _fixed_plants_eval(base, venv, eval_env, eval_seed: int, best_dir: Path, **kwargs):
    """An EvalCallback (`base`) that evaluates on the same plants every time (its env reseeded with
    `eval_seed` before each evaluation), keeps the observation statistics of its best policy beside
    it (best_dir/vecnormalize.npz), and can evaluate the starting policy (`evaluate_start`)."""
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize, sync_envs_normalization

    class FixedPlantsEval(base):
        best_timesteps = 0

        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                self.eval_env.seed(eval_seed)
                before = self.best_mean_reward
                ok = super()._on_step()
                if self.best_mean_reward > before:
                    self._keep_best(self.num_timesteps)
                return ok
            return super()._on_step()

        def _keep_best(self, timesteps: int) -> None:
            self.best_timesteps = timesteps
            if isinstance(venv, VecNormalize):
                best_dir.mkdir(parents=True, exist_ok=True)
                save_obs_stats(venv, best_dir / STATS_FILE)

        def evaluate_start(self, model) -> None:
            if isinstance(venv, VecNormalize):
                sync_envs_normalization(venv, self.eval_env)
            self.eval_env.seed(eval_seed)
            rewards, lengths = evaluate_policy(model, self.eval_env, n_eval_episodes=self.n_eval_episodes,
                                               deterministic=True, return_episode_rewards=True)
            self.best_mean_reward = float(np.mean(rewards))
            self.evaluations_timesteps.append(0)  # the curve starts at the starting policy
            self.evaluations_results.append([float(r) for r in cast(list, rewards)])
            self.evaluations_length.append([int(n) for n in cast(list, lengths)])
            best_dir.mkdir(parents=True, exist_ok=True)
            model.save(best_dir / "best_model.zip")
            self._keep_best(0)

    return FixedPlantsEval(eval_env, **kwargs)


def _continue_evaluations(callback, log_path: Path) -> None:
    """Give a resumed run's EvalCallback the earlier evaluations and best reward, so its history and
    best model continue instead of restarting."""
    path = log_path / EVAL_CURVE
    if not path.is_file():
        return
    with np.load(path, allow_pickle=False) as data:
        callback.evaluations_timesteps = [int(t) for t in data["timesteps"]]
        callback.evaluations_results = [list(r) for r in data["results"]]
        callback.evaluations_length = [list(r) for r in data["ep_lengths"]]
    if callback.evaluations_results:
        callback.best_mean_reward = float(max(np.mean(r) for r in callback.evaluations_results))


def evaluation(model, venv, eval_env, eval_seed: int, run: Path, norm_kwargs, n_eval_episodes: int, every: int,
                resume: bool, select: str):
    """The evaluation environment (normalised as the training's, its statistics frozen) and its callback: every
    `every` calls the same `n_eval_episodes` plants; a resumed run continues its curve, and `select` "best" scores
    the starting policy first."""
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.vec_env import VecNormalize

    if norm_kwargs is not None:
        eval_env = VecNormalize(eval_env, training=False, norm_reward=False, **{k: v for k, v in norm_kwargs.items()
                                                                                if k not in ("norm_reward",)})
    eval_cb = _fixed_plants_eval(EvalCallback, venv, eval_env, eval_seed, run / "best",
                                 n_eval_episodes=n_eval_episodes, eval_freq=every,
                                 best_model_save_path=str(run / "best"), log_path=str(run / "eval"),
                                 deterministic=True, verbose=0)
    if resume:
        _continue_evaluations(eval_cb, run / "eval")
    elif select == "best":
        eval_cb.evaluate_start(model)
    return eval_env, eval_cb


def warmup(steps: int, algo: str) -> list:
    """The callback that holds a PPO's actor (its layers and log std) while the first `steps` train the critic."""
    from stable_baselines3.common.callbacks import BaseCallback

    steps = integer("--critic-warmup", steps, lo=0, hi=10**9)
    if steps == 0:
        return []
    if algo != "ppo":
        raise ValueError(f"--critic-warmup {steps} is for PPO (--init-from a student), not {algo}")

    class ActorHeld(BaseCallback):
        def _actor(self):
            p = self.model.policy
            return [*p.mlp_extractor.policy_net.parameters(), *p.action_net.parameters(), p.log_std]

        def _on_training_start(self) -> None:
            for t in self._actor():
                t.requires_grad_(False)

        def _on_rollout_end(self) -> None:
            if self.model.num_timesteps >= steps:
                for t in self._actor():
                    t.requires_grad_(True)

        def _on_step(self) -> bool:
            return True

    return [ActorHeld()]
