"""`millvib train`: Stable-Baselines3 agents with rl-baselines3-zoo-style hyperparameters.

configs/agents/<algo>.yml holds, per environment id: n_envs, n_timesteps, policy, normalize,
optional env_kwargs, and the algorithm's keyword arguments (strings like "dict(...)" are parsed as
data, never evaluated: `training.hyperparams`). A run folder LOG_DIR/<algo>_<env>_s<seed>/ receives TensorBoard logs,
checkpoints (model and VecNormalize statistics), the best model by periodic evaluation, and at
the end model.zip, vecnormalize.npz (the observation statistics as plain arrays, `normalization`;
vecnormalize.pkl beside it in the run folder for SB3's resume) and card.json (command, seed, steps,
wall time, evaluation). `--save-dir` receives the model, the statistics, the card and the
evaluation curve (evaluations.npz, for scripts/plot_training_curves.py).

Seeds come from the task (configs/tasks.yaml): training environments use the task's first
training seed + 100 * seed + i, the evaluation environments 5000 further on; PID tuning, model
cards (validation) and the benchmark (held-out) have their own ranges, so held-out plants are
never trained on.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from millvib_env._checks import integer, shown, shown_path
from millvib_env._paths import atomic_folder, check_output, check_result_folder, write_text_atomic
from millvib_env.catalog.factory import load_controller
from millvib_env.catalog.agents import ALGOS, SEED_FOLDER, AgentPolicy, agent_env_kwargs, learner
from millvib_env.catalog.manifest import EVAL_CURVE
from millvib_env.catalog.named import resolve_named_gains
from millvib_env.catalog.normalization import STATS_FILE, save_obs_stats
from millvib_env.distributed import run_jobs
from millvib_env.envs.batch import env_mode, env_version
from millvib_env.envs.specs import ENV_SPECS
from millvib_env.tasks import Task, takes_task
from millvib_env.threads import serial_unless_set
from millvib_env.evaluation.benchmark import summarize
from millvib_env.evaluation.evaluate import run_episodes
from millvib_env.training.callbacks import evaluation, warmup
from millvib_env.training.hyperparams import load_hyperparams

__all__ = ["load_hyperparams", "train", "train_seeds", "train_from_cli", "resolve_named_gains", "ALGOS"]

#: the files of an agent folder (`--save-dir`), which a new training of it replaces
AGENT_FILES = frozenset({"card.json", "model.zip", "vecnormalize.npz", EVAL_CURVE})
#: validation plants per model card: the first of the task's validation seeds
N_VALIDATION = 40


def _zero_action_is_a_controller(env_id: str, env_kwargs: dict) -> bool:
    """True where the zero action is a controller (a relative gain action's base, a residual's PID)."""

    acts = env_kwargs.get("actions") or {}
    return bool(env_kwargs.get("residual")) if env_mode(env_id) == "valve" else bool(acts.get("relative"))


def start_at_zero_action(model) -> None:
    """Make a new policy's deterministic action start at (nearly) zero, so an agent whose zero action
    is its base controller starts from it. PPO's action layer is already initialised so (orthogonal,
    gain 0.01); SAC's mean layer is not (a default linear layer: offsets of +-0.5 at the start, 4 %
    dearer than the base on the rolling validation plants), so it is scaled to PPO's gain. sbx's
    actors (flax) get the same: their mean layer is the Dense after the hidden ones."""
    actor_state = getattr(getattr(model, "policy", None), "actor_state", None)
    if actor_state is not None:  # sbx
        if not hasattr(model, "ent_coef_state"):
            return  # sbx PPO: its action layer starts at gain 0.01 already
        import jax.numpy as jnp

        params = actor_state.params
        dense = sorted((k for k in params["params"] if k.startswith("Dense_")), key=lambda k: int(k.split("_")[1]))
        layer = dense[-2]  # [hidden..., mean, log_std]
        mean = dict(params["params"][layer])
        n_in, n_out = mean["kernel"].shape
        q, _ = np.linalg.qr(np.random.default_rng(model.seed).standard_normal((max(n_in, n_out), min(n_in, n_out))))
        mean["kernel"] = jnp.asarray(0.01 * (q if n_in >= n_out else q.T), dtype=mean["kernel"].dtype)
        mean["bias"] = jnp.zeros_like(mean["bias"])
        new = {**params, "params": {**params["params"], layer: mean}}
        model.policy.actor_state = actor_state.replace(params=new)
        return
    import torch

    actor = getattr(model, "actor", None)
    mu = getattr(actor, "mu", None)
    if isinstance(mu, torch.nn.Linear):
        with torch.no_grad():
            torch.nn.init.orthogonal_(mu.weight, gain=0.01)
            mu.bias.zero_()


def jit_noise_key_split(model) -> None:
    """sbx's SAC splits its exploration key with an eager `jax.random.split` at every environment step
    (130 us here, about a tenth of a step); the same split compiled once (8 us) gives the same keys.
    Set on the policy instance of a training run: nothing of it is saved with the model."""
    policy = getattr(model, "policy", None)
    if policy is None or not hasattr(policy, "noise_key") or getattr(policy, "use_sde", False):
        return
    import types

    import jax

    split = jax.jit(lambda key: tuple(jax.random.split(key, 2)))

    def reset_noise(self, batch_size: int = 1) -> None:
        self.key, self.noise_key = split(self.key)

    policy.reset_noise = types.MethodType(reset_noise, policy)


def _checkpoints(folder: Path) -> list[tuple[Path, Path, int]]:
    """(model, statistics, steps) of every checkpoint in `folder`, newest first."""
    ckpts = sorted(folder.glob("rl_model_*_steps.zip"), key=lambda p: int(p.stem.split("_")[-2]), reverse=True)
    return [(c, folder / f"rl_model_vecnormalize_{int(c.stem.split('_')[-2])}_steps.pkl", int(c.stem.split("_")[-2]))
            for c in ckpts]


def _resume_from(cls, folder: Path, venv, normalized: bool, tb: str):
    """The newest intact checkpoint (model and, for a normalised run, its statistics, as a pair),
    loaded onto `venv`; an unreadable or unpaired one is skipped with a message."""
    from stable_baselines3.common.vec_env import VecNormalize

    found = _checkpoints(folder)
    if not found:
        raise ValueError(f"--resume: no checkpoint in {shown_path(folder)}")
    for model_path, stats_path, steps in found:
        if normalized and not stats_path.is_file():
            print(f"--resume: {model_path.name} has no statistics file {stats_path.name}; trying an earlier "
                  "checkpoint", file=sys.stderr)
            continue
        try:
            env = VecNormalize.load(str(stats_path), venv) if normalized else venv
            model = cls.load(model_path, env=env, device="cpu", tensorboard_log=tb)
        except Exception as err:  # a truncated or corrupted file from an interrupted run
            print(f"--resume: {model_path.name} cannot be loaded ({type(err).__name__}); trying an earlier "
                  "checkpoint", file=sys.stderr)
            continue
        if (model_path, stats_path, steps) != found[0]:
            print(f"--resume: continuing from {model_path.name}", file=sys.stderr)
        return model, env, steps
    raise ValueError(f"--resume: no intact checkpoint in {shown_path(folder)} (every one is unreadable or lacks its "
                     "statistics file)")


def train(algo: str, env_id: str = "MillVib-GainSchedule-v1", **kwargs) -> dict:
    """Train one agent; returns its model card (also written to the run folder). Keyword arguments
    as `_train`. The plant runs serially unless MILLVIB_NUM_THREADS says otherwise: the learner
    dominates and idle plant threads slow torch (`millvib_env.threads`)."""

    with serial_unless_set():
        return _train(algo, env_id, **kwargs)


def _check_id_runs_task(env_id: str, task) -> None:
    """A per-task env id (`envs.specs.ENV_SPECS`: one with a config of its own) trains only its own task."""

    spec = ENV_SPECS.get(env_id)
    if spec is not None and spec.config is not None and spec.config != task.config:
        raise ValueError(f"--env {env_id} runs config {shown(spec.config)}, not task {shown(task.name)}'s "
                         f"({shown(task.config)}): pass --task {spec.config} or a generic id")


def _fresh_model(cls, policy, venv, seed: int, run: Path, hp: dict, norm_kwargs: dict | None, env_id: str,
                 env_kwargs: dict, what: str, source=None):
    """A new model on `venv` (wrapped in VecNormalize where the file asks), starting at the zero action where
    that action is a controller, or from `source` (`_start_from`); returns (model, venv)."""
    from stable_baselines3.common.vec_env import VecNormalize

    if norm_kwargs is not None:
        venv = VecNormalize(venv, **{"gamma": hp.get("gamma", 0.99), **norm_kwargs})
    model = _new_model(cls, policy, venv, seed, run, hp, what)
    if _zero_action_is_a_controller(env_id, env_kwargs):
        start_at_zero_action(model)
    _start_from(model, venv, source)
    return model, venv


@takes_task()
def _train(algo: str, env_id: str = "MillVib-GainSchedule-v1", *, task: str | Task = "startup", seed: int = 0,
          n_timesteps: int | None = None,
          config: str | None = None, log_dir: str = "runs", save_dir: str | None = None, resume: bool = False,
          eval_freq: int = 10_000, n_eval_episodes: int = 8, checkpoint_freq: int = 20_000,
          progress: bool = True, command: str | None = None, note: str | None = None, select: str = "last",
          backend: str = "auto", validation_episodes: int = N_VALIDATION, init_from: str | None = None,
          critic_warmup: int = 0) -> dict:
    """Train one agent; returns its model card (also written to the run folder).

    Every evaluation runs the same `n_eval_episodes` plants (the run's evaluation seeds, reseeded each
    time), so the evaluation curve compares policies, not draws. `select`: ship the final policy
    ("last"), the best evaluated one ("best", the starting policy included, with the observation
    statistics of its moment) or the best evaluated one after training started ("trained": never the
    starting policy, so a learned row is a trained policy). `backend`: the learner library, "sb3" or "sbx"
    (JAX; PPO and SAC), with the same hyperparameter files, or "auto" (`catalog.agents.learner`: sbx for SAC where
    it is installed); the card records it. A SAC trained with sbx is saved in SB3's format (`model_format` in the
    card), so `load_controller`, SB3's own `SAC.load` and `millvib export` run it without JAX. The card's
    validation scores the agent on the first `validation_episodes` of the task's validation plants (default 40,
    the shipped agents' figure; fewer for a quick trial, whose card then says so).

    `init_from`: an agent folder (a PPO, e.g. a `millvib distill` student) to start from: its environment (the
    card's env_kwargs, in place of the file's), its network's weights (the file's policy_kwargs must build the same
    network) and its observation statistics; reinforcement learning then fine-tunes it on the task's training
    plants. `critic_warmup`: the first steps train the critic alone, the actor held as it started (a distilled
    student's critic was never trained, and advantages from it would move the actor at random)."""
    if select not in ("last", "best", "trained"):
        raise ValueError(f"--select {shown(select)} is invalid: 'last', 'best' or 'trained'")
    import torch
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback

    from millvib_env.envs.vec_env import make_vec_env

    if str(algo).lower() not in ALGOS:
        raise ValueError(f"algo = {shown(algo)} is invalid: one of {list(ALGOS)}")
    assert isinstance(task, Task)  # a name was resolved by @takes_task
    the_task = task
    _check_id_runs_task(env_id, the_task)
    validation_episodes = integer("--validation-episodes", validation_episodes, lo=1,
                                  hi=len(the_task.seeds["validation"]))  # never a held-out plant
    train_seed, eval_seed = the_task.train_env_seed(seed), the_task.eval_env_seed(seed)
    hp, n_envs, total, policy, normalize = _hyperparams(str(algo).lower(), env_id, config, n_timesteps)
    # the names turned into objects, once: the learner, and the environment's named gain sets
    lrn = learner(algo, backend)
    algo, backend, cls = lrn.algo, lrn.backend, lrn.cls
    env_kwargs = agent_env_kwargs(hp.pop("env_kwargs", None), the_task, env_version(env_id))
    source, env_kwargs = _init_source(init_from, resume, algo, env_id, the_task, env_kwargs)
    torch.set_num_threads(1)  # small networks: threads cost more than they give

    run = _run_folder(Path(log_dir), algo, env_id, the_task, seed, total, save_dir, progress)
    ckpt_dir = run / "checkpoints"
    venv = make_vec_env(env_id, n_envs, seed=train_seed, **env_kwargs)
    eval_env = make_vec_env(env_id, n_eval_episodes, seed=eval_seed, **env_kwargs)
    norm_kwargs = normalize  # `load_hyperparams` read every form as VecNormalize's keywords, or None
    if resume:
        model, venv, done_steps = _resume_from(cls, ckpt_dir, venv, norm_kwargs is not None, str(run / "tb"))
    else:
        (model, venv), done_steps = _fresh_model(cls, policy, venv, seed, run, hp, norm_kwargs, env_id, env_kwargs,
                                                 f"{algo} on {env_id} ({config or 'the default file'})", source), 0
    if backend == "sbx":
        jit_noise_key_split(model)
    eval_env, eval_cb = evaluation(model, venv, eval_env, eval_seed, run, norm_kwargs, n_eval_episodes,
                                    max(eval_freq // n_envs, 1), resume, select)
    callbacks = CallbackList([
        CheckpointCallback(max(checkpoint_freq // n_envs, 1), str(ckpt_dir), save_vecnormalize=True), eval_cb,
        *warmup(critic_warmup, algo)])
    start = time.time()
    model.learn(total_timesteps=max(total - done_steps, 0), callback=callbacks, progress_bar=progress,
                reset_num_timesteps=not resume, tb_log_name=algo)
    wall = time.time() - start
    selected = _keep_policy(run, model, venv, eval_cb, select)
    model_format = lrn.portable(run / "model.zip")
    card = _run_card(algo, env_id, the_task, backend, model_format, env_kwargs, seed, model, n_envs, wall, command,
                     hp, policy, normalize, run, selected, n_eval_episodes, select, note, init_from, source,
                     critic_warmup)
    _finish(card, run, the_task, validation_episodes, progress, None if not save_dir else Path(save_dir))
    venv.close()
    eval_env.close()
    return card


def _hyperparams(algo: str, env_id: str, config: str | None, n_timesteps: int | None):
    """The file's hyperparameters for `env_id`: (the learner's keywords, n_envs, the steps to train, the policy, the
    VecNormalize keywords or None)."""
    hp = load_hyperparams(algo, env_id, config)
    n_envs = int(hp.pop("n_envs"))
    total = int(n_timesteps if n_timesteps is not None else hp.pop("n_timesteps"))
    hp.pop("n_timesteps", None)
    return hp, n_envs, total, hp.pop("policy"), hp.pop("normalize", None)


def _run_folder(log_dir: Path, algo: str, env_id: str, the_task: Task, seed: int, total: int, save_dir,
                progress: bool) -> Path:
    """The run's folder (logs, checkpoints, evaluations), made; with `progress`, said before the run starts (stderr:
    stdout ends with the card's JSON)."""
    run = log_dir / (f"{algo}_{env_id}_s{seed}" if the_task.name == "startup"
                     else f"{algo}_{env_id}_{the_task.name}_s{seed}")
    run.mkdir(parents=True, exist_ok=True)
    if progress:
        print(f"train: {algo} on {env_id} ({the_task.name}, seed {seed}, {total} steps): logs and checkpoints in "
              f"{run}" + (f", the agent to {save_dir}" if save_dir else ""), file=sys.stderr, flush=True)
    return run


def _run_card(algo, env_id, the_task, backend, model_format, env_kwargs, seed, model, n_envs, wall, command, hp,
              policy, normalize, run, selected, n_eval_episodes, select, note, init_from, source,
              critic_warmup) -> dict:
    """The trained agent's card (before its validation): what ran, how long, and what was kept."""
    evals = np.load(run / "eval" / EVAL_CURVE) if (run / "eval" / EVAL_CURVE).exists() else None
    suffix = "" if the_task.name == "startup" else f"-{the_task.name}"
    card = {"name": f"{algo}-{'gain' if 'Gain' in env_id else 'valve'}{suffix}", "algo": algo, "env_id": env_id,
            "task": the_task.name, "backend": backend, "model_format": model_format, "env_kwargs": env_kwargs,
            "seed": seed,
            "n_timesteps": int(model.num_timesteps), "n_envs": n_envs,
            "wall_time_s": round(wall, 1), "command": command or f"millvib train --algo {algo} --env {env_id} "
                                                                  f"--task {the_task.name} --seed {seed}",
            "hyperparameters": {k: (v if isinstance(v, (int, float, str, bool, type(None))) else repr(v))
                                for k, v in hp.items()},
            "policy": policy, "normalize": "None" if normalize is None else repr(normalize),
            "last_eval_mean_reward": float(evals["results"][-1].mean()) if evals is not None else None}
    if selected is not None:
        card["selected"] = {**selected, "how": f"the best of every evaluation on the same {n_eval_episodes} "
                                              "evaluation plants, " + ("the starting policy included"
                                                                       if select == "best" else
                                                                       "the starting policy not among them")}
    if note:
        card["note"] = note
    card.update({"init_from": {"agent": str(init_from), "name": source.name, "seed": source.seed,
                               "trained_by": source.card.get("trained_by", source.card.get("command")),
                               "critic_warmup_steps": int(critic_warmup)}}
                if source is not None else {})  # the card says what it started from
    return card


def _finish(card: dict, run: Path, the_task: Task, validation_episodes: int, progress: bool,
            dest: Path | None) -> None:
    """Score the agent on the task's first validation plants (`validation_result` writes the card it loads with),
    write the card with them into the run folder, and (`dest`, --save-dir) the agent folder: model, statistics,
    curve and card, replaced as a whole."""
    if progress:  # a few seconds with no bar: say what they are
        first = the_task.seeds["validation"].start
        print(f"train: scoring the agent for its card on {the_task.name}'s validation plants {first}-"
              f"{first + validation_episodes - 1}", file=sys.stderr, flush=True)
    card["validation"] = validation_result(run, card, episodes=validation_episodes)
    if dest is not None:
        card["name"] = dest.parent.name if SEED_FOLDER.fullmatch(dest.name) else dest.name
    write_text_atomic(run / "card.json", json.dumps(card, indent=2))
    if dest is not None:
        with atomic_folder(dest) as tmp:
            for src in (run / "model.zip", run / "vecnormalize.npz", run / "eval" / EVAL_CURVE, run / "card.json"):
                if src.exists():
                    shutil.copyfile(src, tmp / src.name)


def _init_source(init_from: str | None, resume: bool, algo: str, env_id: str, task: Task, env_kwargs: dict):
    """The agent `--init-from` names, checked against the run (a PPO of the same id and task), and the env_kwargs the
    run then trains with (the agent's); (None, `env_kwargs`) without one."""
    if init_from is None:
        return None, env_kwargs
    if resume:
        raise ValueError("--init-from and --resume are both given: a run resumes from its own checkpoints")
    source: Any = load_controller(init_from, task)
    if not hasattr(source, "card") or source.algo != "ppo" or algo != "ppo":
        raise ValueError(f"--init-from {shown(init_from)} is invalid here: a PPO agent folder, to fine-tune with "
                         f"--algo ppo (this run: --algo {algo})")
    if source.env_id != env_id:
        raise ValueError(f"--init-from {shown(init_from)} runs {source.env_id}, not --env {env_id}")
    return source, dict(source.env_kwargs)


def _start_from(model, venv, source) -> None:
    """`model` with `source`'s network weights, `venv` with its observation statistics (their count too, so
    the running statistics move as slowly as that many samples make them); nothing where `source` is None."""
    import torch
    from stable_baselines3.common.vec_env import VecNormalize

    if source is None:
        return
    want = source.model.policy.state_dict()
    have = model.policy.state_dict()
    if {k: tuple(v.shape) for k, v in want.items()} != {k: tuple(v.shape) for k, v in have.items()}:
        raise ValueError(f"--init-from {source.name}: its network differs from the one the hyperparameter file's "
                         "policy_kwargs build (net_arch and log_std_init must be the agent's)")
    with torch.no_grad():
        model.policy.load_state_dict(want)
    stats = source.obs_stats
    if stats is not None:
        if not isinstance(venv, VecNormalize):
            raise ValueError(f"--init-from {source.name} normalises its observations: the hyperparameter file needs "
                             "normalize")
        rms: Any = venv.obs_rms
        rms.mean, rms.var, rms.count = stats.mean.copy(), stats.var.copy(), float(stats.count)


def _new_model(cls, policy, venv, seed: int, run: Path, hp: dict, what: str):
    """A new learner; hyperparameters the learner refuses are a ValueError of one line."""
    try:
        return cls(policy, venv, seed=seed, device="cpu", tensorboard_log=str(run / "tb"), verbose=0, **hp)
    except (TypeError, ValueError, AssertionError, KeyError) as err:  # a key or value SB3 refuses
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ValueError(f"hyperparameters for {what} are not accepted by {cls.__name__}: {first}") from None


def _keep_policy(run: Path, model, venv, eval_cb, select: str) -> dict | None:
    """Write the shipped policy and its observation statistics into the run folder: the final one, or
    (`select` "best") the best evaluated one; returns what was selected, or None for the final one."""
    from stable_baselines3.common.vec_env import VecNormalize

    normalized = isinstance(venv, VecNormalize)
    if normalized:
        venv.save(str(run / "vecnormalize.pkl"))
    if select in ("best", "trained") and (run / "best" / "best_model.zip").is_file():
        shutil.copyfile(run / "best" / "best_model.zip", run / "model.zip")
        if normalized:
            shutil.copyfile(run / "best" / STATS_FILE, run / STATS_FILE)
        return {"timesteps": int(eval_cb.best_timesteps), "mean_reward": float(eval_cb.best_mean_reward)}
    model.save(run / "model.zip")
    if normalized:
        save_obs_stats(venv, run / STATS_FILE)
    return None


def validation_result(folder: str | Path, card: dict | None = None, episodes: int = N_VALIDATION) -> dict:
    """Mean severity, tracking and cost of the agent in `folder` on the first `episodes` validation plants."""

    folder = Path(folder)
    if card is not None:  # the card is written after this: give the loader what it needs
        write_text_atomic(folder / "card.json", json.dumps(card, indent=2))
    agent = AgentPolicy(folder)
    first = agent.task.seeds["validation"].start
    seeds = list(range(first, first + episodes))
    summary = summarize(run_episodes(agent, seeds, task=agent.task))
    keep = ("severity_mean", "tracking_rms_um_mean", "cost_mean", "cost_cvar20", "diverged_rate", "episodes")
    return {"seeds": f"{seeds[0]}-{seeds[-1]}", **{k: summary[k] for k in keep}}


@takes_task()
def train_seeds(seeds, *, task: str | Task = "startup", jobs: int = 2, save_dir: str | None = None,
                ray: str | None = None, cpus_per_seed: float = 1.0, **kwargs) -> list[dict]:
    """Train several seeds: in `jobs` local worker processes (`distributed.run_jobs`: forks of a fork server
    that imported torch and SB3 once; no thread pool or torch state of this process is inherited), or each as a
    Ray task asking for `cpus_per_seed` CPUs (`ray`: "" for a local cluster, or an address). Seed s is saved to
    `save_dir`/seed-<s>/. Returns the cards in seed order."""

    seeds = list(dict.fromkeys(seeds))
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"--jobs {shown(jobs)} is invalid: a whole number >= 1")
    assert isinstance(task, Task)  # a name was resolved by @takes_task
    the_task = task
    for s in seeds:
        the_task.train_env_seed(s)  # refuses a seed outside the training range before anything runs
    job_args = [{**kwargs, "task": the_task, "seed": s, "progress": False,
                 "save_dir": None if save_dir is None else str(Path(save_dir) / f"seed-{s}")} for s in seeds]
    return run_jobs(train, job_args, ray=ray, processes=jobs, num_cpus=cpus_per_seed,
                    preload=("torch", "torch._dynamo", "stable_baselines3"))


def train_from_cli(args) -> int:

    check_output(args.log_dir, "--log-dir", folder=True)
    if args.save_dir is not None:
        for seed in (args.seeds or [args.seed]):  # each seed's folder is replaced as a whole
            dest = Path(args.save_dir) / f"seed-{seed}" if args.seeds else Path(args.save_dir)
            check_result_folder(dest, "--save-dir", "train", others=(("--log-dir", args.log_dir),),
                                own_files=AGENT_FILES)
            inside_run = Path(dest).resolve().relative_to(Path(args.log_dir).resolve()).parts[:1] \
                if Path(args.log_dir).resolve() in Path(dest).resolve().parents else ()
            if inside_run and inside_run[0].startswith(f"{args.algo}_"):
                raise ValueError(f"--save-dir {shown_path(dest)} lies inside the run folder "
                                 f"{Path(args.log_dir) / inside_run[0]} (checkpoints, logs), which it would replace: "
                                 "put it outside --log-dir's run folders")
    for flag, value in (("--n-timesteps", args.n_timesteps), ("--eval-freq", args.eval_freq),
                        ("--n-eval-episodes", args.n_eval_episodes), ("--checkpoint-freq", args.checkpoint_freq),
                        ("--jobs", args.jobs), ("--validation-episodes", args.validation_episodes)):
        if value is not None and value < 1:
            raise ValueError(f"{flag} {value} is invalid: a whole number >= 1")
    common = dict(algo=args.algo, env_id=args.env, task=args.task, n_timesteps=args.n_timesteps, config=args.config,
                  log_dir=args.log_dir, resume=args.resume, eval_freq=args.eval_freq,
                  n_eval_episodes=args.n_eval_episodes, checkpoint_freq=args.checkpoint_freq,
                  command="millvib " + " ".join(sys.argv[1:]), note=args.note, select=args.select,
                  backend=args.backend, validation_episodes=args.validation_episodes, init_from=args.init_from,
                  critic_warmup=args.critic_warmup)
    if args.seeds:
        cards = train_seeds(args.seeds, jobs=args.jobs, save_dir=args.save_dir, ray=args.ray, **common)
        print(json.dumps(cards, indent=2))
        return 0
    if args.ray is not None:
        cards = train_seeds([args.seed], save_dir=None, ray=args.ray, **common)
        print(json.dumps(cards[0], indent=2))
        return 0
    card = train(seed=args.seed, save_dir=args.save_dir, progress=not args.quiet, **common)
    print(json.dumps(card, indent=2))
    return 0
