"""An experiment: PPO fine-tuning of a DAgger student with a privileged critic (an asymmetric actor-critic).

    MILLVIB_NUM_THREADS=1 python scripts/privileged_critic.py agents/dagger-on-pid-pf-preview-varied/seed-0 \
        --steps 600000 --warmup 200000 --eval-every 100000 --out /tmp/pc-varied-0

The actor is the student's network and reads what the student reads (its observation, normalised by the student's
own statistics, held fixed). The critic, which the student never had, reads that and what only the simulator knows:
the plant's parameters, its state, and the rolling force's exact course (steps and eccentricity) over the next
100 ms. Advantages from such a critic leave out most of what the disturbances do to the return, which a critic of
the actor's observation cannot predict; that variance is what moved the plain fine-tuning's actor at random
(configs/agents/on-preview/ppo.yml). The critic trains alone first (`--warmup` steps, the actor's step size 0),
then both, the actor with a small step. Every `--eval-every` steps the actor, put back into the student's own
network, is scored on the student's validation plants (the same 40 the distillation selected on, so the start is
the student's own number). It writes `curve.json` (steps, validation cost) and the best actor as an agent folder
(`best/`), the student's card and statistics beside it; nothing is shipped by this script.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnvWrapper, VecNormalize
from torch import nn

from millvib_env.catalog.agents import AgentPolicy
from millvib_env.envs.observation import OBS_SCALES, slog
from millvib_env.envs.vec_env import make_vec_env
from millvib_env.params import MillParams
from millvib_env.training.finetune import actor_into_student, copy_actor, split_optimizer, split_rates_ppo
from millvib_env.training.train import validation_result

#: the force course's look-aheads the critic reads (control samples, 0.5 ms each): to 100 ms
AHEAD = np.array([0, 1, 2, 4, 8, 16, 24, 32, 48, 64, 96, 128, 160, 200])
PARAMS = ("c1", "Ct", "beta_e", "mt", "FL")


class Privileged(VecEnvWrapper):
    """The actor's observation normalised by the student's fixed statistics, then the critic's privileged
    features (running-normalised): the plant's parameters (log, relative to the nominal), its state, the force
    course ahead and the episode's clock."""

    def __init__(self, venv, stats, plain: bool = False):
        self.core = venv.unwrapped.core if hasattr(venv, "unwrapped") else venv.venv.core
        self.stats = stats
        self.n_actor = int(venv.observation_space.shape[0])
        n_state = len(self.core.plant_state(0))
        self.n_priv = len(PARAMS) + n_state + len(AHEAD) + 1
        space = spaces.Box(-np.inf, np.inf, (self.n_actor + self.n_priv,), np.float32)
        super().__init__(venv, observation_space=space)
        self.rms = RunningMeanStd(shape=(self.n_priv,))
        self.training, self.plain = True, plain
        self.nominal = np.log([getattr(MillParams(), p) for p in PARAMS])
        self.last = np.zeros((venv.num_envs, self.n_priv), np.float32)

    def _features(self) -> np.ndarray:
        core, n = self.core, self.num_envs
        idx = np.arange(n)
        params = np.log([[core.current_params(i)[p] for p in PARAMS] for i in idx]) - self.nominal
        state = core.plant_state(idx)
        k, t = core.control_sample(idx), core.time_now(idx)
        dt = core.settings.loop.dt_s
        cols = np.minimum(k[:, None] + AHEAD[None, :], core.course_samples - 1)
        force = core.force_course(idx[:, None], cols, t[:, None] + AHEAD[None, :] * dt)
        force = slog(force, *OBS_SCALES["load_force"][2:])
        clock = (k / max(core.course_samples - 1, 1))[:, None]
        raw = np.concatenate([params, state, force, clock], axis=1)
        if self.plain:
            return np.zeros_like(raw, dtype=np.float32)
        if self.training:
            self.rms.update(raw)
        return np.clip((raw - self.rms.mean) / np.sqrt(self.rms.var + 1e-8), -10, 10).astype(np.float32)

    def _join(self, obs: np.ndarray, priv: np.ndarray) -> np.ndarray:
        return np.concatenate([self.stats.normalize(obs.astype(np.float32)), priv], axis=1).astype(np.float32)

    def reset(self):
        obs = self.venv.reset()
        self.last = self._features()
        return self._join(obs, self.last)

    def step_wait(self):
        obs, rew, done, infos = self.venv.step_wait()
        priv = self._features()
        for i in np.flatnonzero(done):  # the episode's last state: its features before the reset (one step old)
            term = infos[i].get("terminal_observation")
            if term is not None:
                infos[i]["terminal_observation"] = self._join(term[None], self.last[i][None])[0]
        self.last = priv
        return self._join(obs, priv), rew, done, infos


class SplitMlp(nn.Module):
    """The student's actor (its first `n_actor` inputs) and a critic of every input."""

    def __init__(self, n_actor: int, n_all: int, pi: list[int], vf: list[int], act: type[nn.Module]):
        super().__init__()
        self.n_actor = n_actor

        def mlp(n_in, sizes):
            layers: list[nn.Module] = []
            for size in sizes:
                layers += [nn.Linear(n_in, size), act()]
                n_in = size
            return nn.Sequential(*layers)

        self.policy_net, self.value_net = mlp(n_actor, pi), mlp(n_all, vf)
        self.latent_dim_pi, self.latent_dim_vf = pi[-1], vf[-1]

    def forward(self, features):
        return self.forward_actor(features), self.forward_critic(features)

    def forward_actor(self, features):
        return self.policy_net(features[:, :self.n_actor])

    def forward_critic(self, features):
        return self.value_net(features)


class AsymmetricPolicy(ActorCriticPolicy):
    """An SB3 actor-critic whose actor reads the first `n_actor` inputs only."""

    def __init__(self, *args, n_actor: int = 0, pi=(256, 256), vf=(256, 256), **kwargs):
        self.n_actor, self.pi_sizes, self.vf_sizes = n_actor, list(pi), list(vf)
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = SplitMlp(self.n_actor, self.features_dim, self.pi_sizes, self.vf_sizes,
                                      self.activation_fn)


class Scored(BaseCallback):
    """The critic's warm-up, then the actor's steps; the actor scored every `every` steps."""

    def __init__(self, warmup: int, actor_lr: float, every: int, student: Path, out: Path, episodes: int):
        super().__init__()
        self.start = time.time()
        self.warmup, self.actor_lr, self.every, self.student, self.out = warmup, actor_lr, every, student, out
        self.episodes, self.next, self.curve, self.best = episodes, every, [], np.inf

    def score(self) -> float:
        actor_into_student(self.model, self.student, self.out / "now")
        cost = validation_result(self.out / "now", episodes=self.episodes)["cost_mean"]
        self.curve.append({"steps": int(self.num_timesteps), "cost_mean": cost,
                           "wall_s": round(time.time() - self.start),
                           "explained_variance": round(getattr(self.model, "explained", float("nan")), 4)})
        if cost < self.best:
            self.best = cost
            if (self.out / "best").exists():
                shutil.rmtree(self.out / "best")
            shutil.copytree(self.out / "now", self.out / "best")
        (self.out / "curve.json").write_text(json.dumps(self.curve, indent=1))
        print(json.dumps(self.curve[-1]), flush=True)
        return cost

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.warmup:
            self.model.actor_lr = self.actor_lr
        if self.num_timesteps >= self.next:
            self.next += self.every
            self.score()
        return True


def confirm(student: Path, tuned: Path, n: int) -> int:
    """The student and the fine-tuned actor on validation plants 40 .. 40 + n (not those the scores selected on)."""
    from validation_pairs import pair  # scripts/validation_pairs.py, beside this one

    base = AgentPolicy(student)
    print(json.dumps(pair(base, AgentPolicy(tuned), base.task, skip=40, plants=n)))
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("student")
    p.add_argument("--steps", type=int, default=600_000)
    p.add_argument("--warmup", type=int, default=200_000)
    p.add_argument("--eval-every", type=int, default=100_000)
    p.add_argument("--episodes", type=int, default=40, help="validation plants a score runs on")
    p.add_argument("--actor-lr", type=float, default=3e-5)
    p.add_argument("--critic-lr", type=float, default=3e-4)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument("--n-envs", type=int, default=16)
    p.add_argument("--n-steps", type=int, default=256)
    p.add_argument("--n-epochs", type=int, default=5)
    p.add_argument("--clip", type=float, default=0.1)
    p.add_argument("--target-kl", type=float, default=0.01)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--plain-critic", action="store_true",
                   help="the control: the privileged features held at zero (a critic of the actor's observation)")
    p.add_argument("--out", required=True)
    p.add_argument("--confirm", type=int, default=0, metavar="N",
                   help="instead of training: the student against OUT/best on N validation plants after the 40 the "
                        "scores select on (paired 95 %% interval)")
    a = p.parse_args(argv)
    if a.confirm:
        return confirm(Path(a.student), Path(a.out) / "best", a.confirm)
    torch.set_num_threads(1)
    student_folder = Path(a.student)
    student = AgentPolicy(student_folder)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    task = student.task
    venv = make_vec_env(student.env_id, a.n_envs, seed=task.train_env_seed(a.seed), **student.env_kwargs)
    env = VecNormalize(Privileged(venv, student.obs_stats, a.plain_critic), norm_obs=False, norm_reward=True,
                       gamma=a.gamma)
    src = student.model.policy
    kwargs = dict(n_actor=env.observation_space.shape[0] - env.venv.n_priv, activation_fn=src.activation_fn,
                  log_std_init=float(src.log_std.detach().mean()))
    model = split_rates_ppo()(AsymmetricPolicy, env, n_steps=a.n_steps, batch_size=1024, n_epochs=a.n_epochs,
                       gamma=a.gamma, gae_lambda=0.95, clip_range=a.clip, target_kl=a.target_kl, ent_coef=0.0,
                       seed=a.seed, device="cpu", policy_kwargs=kwargs, verbose=0)
    copy_actor(src, model.policy)
    split_optimizer(model)
    model.critic_lr = a.critic_lr
    cb = Scored(a.warmup, a.actor_lr, a.eval_every, student_folder, out, a.episodes)
    cb.model = model
    start = cb.score()  # the student itself, through the same path
    print(f"start (the student): {start:.5f}", flush=True)
    model.learn(total_timesteps=a.steps, callback=cb)
    print(json.dumps({"start": start, "best": cb.best, "curve": cb.curve}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
