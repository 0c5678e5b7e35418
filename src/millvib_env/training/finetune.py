"""`millvib finetune`: reinforcement learning (PPO) on top of a distilled student, stopped on validation plants.

A DAgger student (`millvib distill`) imitates its teacher, `mpc-preview`, which reads the plant's true state. PPO
then moves the student on the task's own reward, from what the student reads only. At the loop's 2 kHz a return
carries the noise of many disturbances: with an untrained critic, or the actor's steps as large as the critic's,
PPO moved the students at random (configs/agents/on-preview/ppo.yml). The recipe that did not:

1. the actor is the student's network and reads what the student reads, normalised by the student's own
   statistics, held fixed (a running normalisation would change the actor's input under it);
2. the reward is each period's share of the episode's cost (`envs.reward.EpisodeCostReward`), not the config's
   sum of each period's own RMS, which rewards quieting the quiet periods while the cost is set by the loud ones;
3. a new critic (two layers of 256, of the same observation) learns alone for the first `warmup` steps, the
   actor's step size 0, with its own step size (`critic_lr`, default 3e-4);
4. then the actor learns too, with a small step (`actor_lr`, default 3e-5), PPO's clip 0.1 and a KL stop at 0.01,
   on the training plants of the student's seed (`Task.train_env_seed`);
5. every `eval_every` steps after the warm-up the actor, put back into the student's network, is scored on the
   task's first validation plants (the 40 the student was selected on). The agent written is the best of those
   scores; the student itself is never among them, so the row is a trained policy even where it costs more.
   The scores fall for the first 50-150 k steps of the actor and rise after (measured on rolling): stopping on
   validation is part of the recipe, not a safeguard.

The agent folder holds the student's network with the new actor, the student's statistics and a card: the
student it started from, every score (`curve`), the one selected and the run's time. It loads as any agent and
runs in the benchmark beside its student, against the classical controller of its information (`on`).
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from millvib_env._checks import integer, real
from millvib_env._paths import agents_dir, atomic_folder, check_result_folder, write_text_atomic
from millvib_env.catalog.agents import AgentPolicy, read_card
from millvib_env.catalog.manifest import AGENT_FILES, write_manifest
from millvib_env.envs.reward import EpisodeCostReward
from millvib_env.training.train import N_VALIDATION, validation_result

__all__ = ["finetune", "finetune_from_cli", "ACTOR_KEYS"]

#: the policy's parameters that make the actor (SB3's ActorCriticPolicy): its layers, its output and the log std
ACTOR_KEYS = ("mlp_extractor.policy_net", "action_net", "log_std")
#: the critic's hidden layers
CRITIC_NET = [256, 256]


def split_rates_ppo():
    """SB3's PPO whose actor and critic take steps of their own size (`actor_lr`, 0 during the critic's warm-up, and
    `critic_lr`); the optimiser's parameter groups carry an ``actor`` flag."""
    from stable_baselines3 import PPO

    class SplitRates(PPO):
        actor_lr = 0.0
        critic_lr = 3e-4
        explained = float("nan")

        def train(self) -> None:
            super().train()
            self.explained = float(self.logger.name_to_value.get("train/explained_variance", float("nan")))

        def _update_learning_rate(self, optimizers) -> None:
            self.logger.record("train/actor_lr", self.actor_lr)
            for opt in optimizers if isinstance(optimizers, list) else [optimizers]:
                for group in opt.param_groups:
                    group["lr"] = self.actor_lr if group.get("actor") else self.critic_lr

    return SplitRates


def split_optimizer(model) -> None:
    """Give `model` (a `split_rates_ppo` model) an Adam whose first parameter group is the actor's."""
    import torch

    named = list(model.policy.named_parameters())
    actor = [p for n, p in named if n.startswith(ACTOR_KEYS)]
    critic = [p for n, p in named if not n.startswith(ACTOR_KEYS)]
    groups: list[dict[str, Any]] = [{"params": actor, "actor": True}, {"params": critic}]
    model.policy.optimizer = torch.optim.Adam(groups, eps=1e-5)


def copy_actor(source_policy, target_policy) -> None:
    """The actor's weights of `source_policy` into `target_policy` (SB3 ActorCriticPolicy, the same actor)."""
    state = target_policy.state_dict()
    state.update({k: v for k, v in source_policy.state_dict().items() if k.startswith(ACTOR_KEYS)})
    target_policy.load_state_dict(state)


def actor_into_student(model, student: Path, folder: Path, card: dict | None = None) -> None:
    """An agent folder: the student's (folder `student`) statistics and network with `model`'s actor, and `card`
    (the student's where None)."""
    from stable_baselines3 import PPO

    if folder.exists():
        shutil.rmtree(folder)
    shutil.copytree(student, folder)
    net = PPO.load(student / "model.zip", device="cpu")
    copy_actor(model.policy, net.policy)
    net.save(folder / "model.zip")
    if card is not None:
        write_text_atomic(folder / "card.json", json.dumps(card, indent=2))


def _fixed_normalisation(venv, stats):
    """`venv` whose observations are normalised by the student's statistics (held fixed) and whose rewards are
    normalised as SB3's VecNormalize does (running)."""
    from stable_baselines3.common.vec_env import VecEnvWrapper, VecNormalize

    class FixedObs(VecEnvWrapper):
        def reset(self):
            return stats.normalize(self.venv.reset())

        def step_wait(self):
            obs, rew, done, infos = self.venv.step_wait()
            for i in np.flatnonzero(done):
                term = infos[i].get("terminal_observation")
                if term is not None:
                    infos[i]["terminal_observation"] = stats.normalize(term[None])[0]
            return stats.normalize(obs), rew, done, infos

    return VecNormalize(FixedObs(venv), norm_obs=False, norm_reward=True)


def _checked(student, steps, warmup, eval_every, actor_lr, critic_lr, gamma, validation_episodes, n_envs, n_steps):
    """The run's numbers checked (one-line ValueError naming the field), and the student loaded."""
    steps = integer("steps", steps, lo=1, hi=10**9)
    warmup = integer("warmup", warmup, lo=0, hi=steps - 1)
    eval_every = integer("eval_every", eval_every, lo=1, hi=10**9)  # past the end: the end alone is scored
    real("actor_lr", actor_lr, lo=0.0, lo_open=True, hi=1.0)
    real("critic_lr", critic_lr, lo=0.0, lo_open=True, hi=1.0)
    real("gamma", gamma, lo=0.0, hi=1.0)
    integer("n_envs", n_envs, lo=1, hi=256)
    integer("n_steps", n_steps, lo=2, hi=1 << 16)
    folder = Path(student)
    if not (folder / "card.json").is_file():
        raise ValueError(f"student = {str(student)!r} is invalid: an agent seed folder with card.json (e.g. "
                         "agents/dagger-on-pid-pf-preview-rolling/seed-0)")
    agent = AgentPolicy(folder)
    if agent.algo != "ppo" or agent.recurrent or agent.obs_stats is None:
        raise ValueError(f"student = {str(student)!r} is invalid: a PPO agent with observation statistics (a "
                         f"`millvib distill` student), not a {agent.algo} agent")
    validation_episodes = integer("validation_episodes", validation_episodes, lo=1,
                                  hi=len(agent.task.seeds["validation"]))
    return folder, agent, steps, warmup, eval_every, validation_episodes


def finetune(student: str | Path, *, save_dir: str | Path, steps: int = 600_000, warmup: int = 200_000,
             eval_every: int = 50_000, actor_lr: float = 3e-5, critic_lr: float = 3e-4,
             validation_episodes: int = N_VALIDATION, n_envs: int = 16, n_steps: int = 256, n_epochs: int = 5,
             gamma: float = 0.99, reward: str = "episode-cost", progress: bool = True,
             command: str | None = None) -> dict:
    """Fine-tune the student in the agent seed folder `student` by PPO (module docstring); write the agent folder
    `save_dir` and return its card. The student's seed is the run's: its training plants and PPO's seed. `reward`:
    what PPO maximises, "episode-cost" (each period by what it adds to the episode's cost,
    `envs.reward.EpisodeCostReward`; the default) or "config" (the environment's reward: each period's own RMS); the
    validation scores are the cost either way."""
    import torch

    folder, agent, steps, warmup, eval_every, validation_episodes = _checked(
        student, steps, warmup, eval_every, actor_lr, critic_lr, gamma, validation_episodes, n_envs, n_steps)
    from millvib_env.envs.vec_env import make_vec_env

    if reward not in ("config", "episode-cost"):
        raise ValueError(f"reward = {reward!r} is invalid: 'config' or 'episode-cost'")
    torch.set_num_threads(1)
    torch.manual_seed(agent.seed)
    task = agent.task
    cost = EpisodeCostReward() if reward == "episode-cost" else None
    venv = make_vec_env(agent.env_id, n_envs, seed=task.train_env_seed(agent.seed), reward_fn=cost,
                        **agent.env_kwargs)
    if cost is not None:
        core: Any = venv.unwrapped if hasattr(venv, "unwrapped") else venv  # SB3's wrapper forwards to the batch
        cost.follow(core.core.reward)
    env = _fixed_normalisation(venv, agent.obs_stats)
    src = agent.model.policy
    pi = [m.out_features for m in src.mlp_extractor.policy_net if hasattr(m, "out_features")]
    batch = min(1024, n_envs * n_steps)
    model = split_rates_ppo()("MlpPolicy", env, n_steps=n_steps, batch_size=batch, n_epochs=n_epochs, gamma=gamma,
                              gae_lambda=0.95, clip_range=0.1, target_kl=0.01, ent_coef=0.0, seed=agent.seed,
                              device="cpu", verbose=0,
                              policy_kwargs=dict(activation_fn=src.activation_fn,
                                                 log_std_init=float(src.log_std.detach().mean()),
                                                 net_arch=dict(pi=pi, vf=CRITIC_NET)))
    copy_actor(src, model.policy)
    split_optimizer(model)
    model.critic_lr = float(critic_lr)
    work = Path(tempfile.mkdtemp(prefix="millvib-finetune-"))
    try:
        rollout = n_envs * n_steps  # PPO learns in whole rollouts: the run ends at the first multiple past `steps`
        run = _Scores(folder, work, validation_episodes, warmup, float(actor_lr), eval_every,
                      -(-steps // rollout) * rollout, progress,
                      f"finetune {agent.name} seed {agent.seed}")
        start = time.time()
        model.learn(total_timesteps=steps, callback=run.callback())
        run.close()
        card = _card(agent, folder, save_dir, run, dict(steps=steps, warmup=warmup, eval_every=eval_every,
                                                        actor_lr=actor_lr, critic_lr=critic_lr, n_envs=n_envs,
                                                        n_steps=n_steps, n_epochs=n_epochs, gamma=gamma,
                                                        batch_size=batch, clip_range=0.1, target_kl=0.01,
                                                        critic_net=CRITIC_NET, reward=reward),
                     time.time() - start, command)
        assert run.best is not None  # eval_every <= steps - warmup is not required: the last step is always scored
        write_text_atomic(run.best / "card.json", json.dumps(card, indent=2))
        with atomic_folder(Path(save_dir)) as tmp:
            for name in ("model.zip", "vecnormalize.npz", "card.json"):
                shutil.copyfile(run.best / name, tmp / name)
    finally:
        env.close()
        shutil.rmtree(work, ignore_errors=True)
    return card


class _Scores:
    """The actor scored on the validation plants every `every` steps after the warm-up and at the run's end; the
    best kept (a folder under `work`)."""

    def __init__(self, student: Path, work: Path, episodes: int, warmup: int, actor_lr: float, every: int,
                 steps: int, progress: bool, desc: str):
        self.student, self.work, self.episodes = student, work, episodes
        self.warmup, self.actor_lr, self.every, self.steps = warmup, actor_lr, every, steps
        self.curve: list[dict] = []
        self.best: Path | None = None
        self.best_cost = np.inf
        self.best_steps = 0
        self.best_val: dict = {}
        self.start = time.time()
        self.bar: Any = None
        if progress:
            from tqdm.auto import tqdm
            self.bar = tqdm(total=steps, unit="step", desc=desc)

    def score(self, model) -> None:
        steps = int(model.num_timesteps)
        folder = self.work / f"at-{steps}"
        actor_into_student(model, self.student, folder)
        val = validation_result(folder, episodes=self.episodes)
        self.curve.append({"steps": steps, "cost_mean": val["cost_mean"], "cost_cvar20": val["cost_cvar20"],
                           "critic_explained_variance": round(float(getattr(model, "explained", np.nan)), 4),
                           "wall_s": round(time.time() - self.start, 1)})
        if val["cost_mean"] < self.best_cost:
            if self.best is not None:
                shutil.rmtree(self.best)
            self.best, self.best_cost, self.best_steps, self.best_val = folder, val["cost_mean"], steps, val
        else:
            shutil.rmtree(folder)
        if self.bar is not None:
            self.bar.set_postfix_str(f"validation {val['cost_mean']:.4f}, best {self.best_cost:.4f} at "
                                     f"{self.best_steps} steps")

    def callback(self):
        from stable_baselines3.common.callbacks import BaseCallback

        run = self

        class Scored(BaseCallback):
            next = run.warmup + run.every

            def _on_step(self) -> bool:
                model: Any = self.model  # a split_rates_ppo model
                n = model.num_timesteps
                if n >= run.warmup:
                    model.actor_lr = run.actor_lr
                if run.bar is not None:
                    run.bar.update(n - run.bar.n)
                if n >= self.next:
                    self.next += run.every
                    run.score(self.model)
                return True

            def _on_training_end(self) -> None:
                if not run.curve or run.curve[-1]["steps"] < self.model.num_timesteps:
                    run.score(self.model)

        return Scored()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _card(agent, student: Path, save_dir, run: _Scores, hp: dict, wall: float, command: str | None) -> dict:
    """The fine-tuned agent's card: the student's environment and information, what the run did and what it kept."""
    own = read_card(student / "card.json")
    save_dir = Path(save_dir)
    card = {k: v for k, v in own.items() if k not in ("iterations", "selected", "validation", "trained_by", "command",
                                                      "wall_time_s", "n_timesteps")}
    card.update({
        "name": save_dir.parent.name if save_dir.name.startswith("seed-") else save_dir.name,
        "algo": "ppo", "backend": "sb3",
        "policy": "MlpPolicy (the student's actor, fine-tuned; a critic of 256 x 256)",
        "trained_by": f"PPO fine-tuning of {agent.name} seed {agent.seed}: the critic alone for {hp['warmup']} steps "
                      f"(step {hp['critic_lr']:g}), then the actor too (step {hp['actor_lr']:g}), to "
                      f"{hp['steps']} steps on the training plants of seed {agent.seed}, the observation statistics "
                      "the student's (fixed), the reward "
                      + ("each period's share of the episode's cost" if hp["reward"] == "episode-cost"
                         else "the environment's"),
        "command": command or f"millvib finetune {student} --save-dir {save_dir}",
        "init_from": {"agent": str(student), "name": agent.name, "seed": agent.seed,
                      "trained_by": own.get("trained_by"), "command": own.get("command"),
                      "validation": own.get("validation")},
        "hyperparameters": hp,
        "n_timesteps": int(run.best_steps),
        "wall_time_s": round(wall, 1),
        "curve": run.curve,
        "selected": {"steps": int(run.best_steps),
                     "how": f"the best validation cost of the actor's {len(run.curve)} scores after the critic's "
                            "warm-up (the student itself never among them)"},
        "validation": run.best_val,
    })
    return card


def finetune_from_cli(args) -> int:
    """`millvib finetune`: the run, its summary printed, the manifest updated where the agent is a shipped one."""
    import sys

    check_result_folder(args.save_dir, "--save-dir", "finetune", own_files=AGENT_FILES)
    card = finetune(args.student, save_dir=args.save_dir, steps=args.steps, warmup=args.warmup,
                    eval_every=args.eval_every, actor_lr=args.actor_lr, critic_lr=args.critic_lr,
                    validation_episodes=args.validation_episodes, n_envs=args.n_envs, n_steps=args.n_steps,
                    gamma=args.gamma, reward=args.reward, progress=not args.quiet,
                    command="millvib " + " ".join(sys.argv[1:]))
    print(json.dumps({k: card[k] for k in ("name", "task", "seed", "trained_by", "validation", "selected")}, indent=2))
    print(f"the student on the same plants: cost {card['init_from']['validation']['cost_mean']:.5g}")
    if Path(agents_dir()).resolve() in Path(args.save_dir).resolve().parents:
        print(f"updated {write_manifest()}")
    print(f"wrote {args.save_dir}")
    return 0
