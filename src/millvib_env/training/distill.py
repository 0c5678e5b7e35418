"""`millvib distill`: a deployable residual valve policy learned from the MPC oracle (teacher-student, DAgger).

The room a preview opens (`millvib headroom`: `mpc-preview` against `pid-pf-robust`) is taken by an oracle
that reads the plant's true state. A deployable controller reads only the loop's sensors and the preview.
PPO from scratch at the loop's 2 kHz did not find it (measured: flat evaluation returns over 0.8 M steps on
rolling, two seeds). So the student is taught by the oracle (Ross et al., DAgger, 2011; the privileged
teacher of "learning by cheating"):

1. the student runs in the residual valve environment on top of the reference (`pid-pf-robust`), reading
   what a mill measures (position error and its filtered derivative, pressure, the load cells' force), those
   channels' history (`observation.history_samples`) and the preview (`observation.preview_samples`);
   iteration 0 runs the reference alone (the zero action);
2. at every loop sample the teacher (`control.mpc`, attached to the same environments) computes the
   command it would send from the true state, and the label is the residual that would make the loop's
   command the teacher's: ``(u_teacher - u_pid) / residual_range`` (u_pid: the digital PID's own command at
   that sample), clipped to the action's [-1, 1];
3. the pairs of every iteration are pooled (DAgger's aggregation) and the student's network (an SB3 PPO
   MlpPolicy's actor, so the result is an ordinary SB3 agent folder) is fitted by least squares on the
   observations normalised by the pooled statistics (written as vecnormalize.npz);
4. the next iteration runs the new student (its own states, labelled by the teacher).

Each iteration's student is scored on the task's validation plants; the shipped one is the best of those
scores, never iteration 0's reference. Every episode is a training plant of the training seed
(`Task.train_env_seed`: its 100 plants in turn; past them an iteration visits them again under its new student); the
numbers of the run are in the card.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from millvib_env._checks import integer, real
from millvib_env._paths import atomic_folder, write_text_atomic
from millvib_env.catalog.factory import load_controller
from millvib_env.catalog.named import resolve_named_gains_for
from millvib_env.catalog.normalization import ObsStats
from millvib_env.control.preview import DEFAULT_PREVIEW, preview_env_kwargs
from millvib_env.envs.batch import EpisodeBatch
from millvib_env.tasks import TRAIN_SEED_STRIDE, Task, takes_task
from millvib_env.training.distill_journal import open_distill_journal
from millvib_env.training.train import N_VALIDATION, validation_result

__all__ = ["distill", "DEFAULT_PREVIEW", "DEFAULT_HISTORY", "DEFAULT_LOOP_SAMPLE", "student_env_kwargs"]

#: the measured channels' history the student reads (control samples: 0.5-16 ms before)
DEFAULT_HISTORY = (1, 2, 4, 8, 16, 32)
#: the loop's sample the student reads (`observation.loop_sample`): the one its action is added to
DEFAULT_LOOP_SAMPLE = "current"
#: the environment a student acts in
ENV_ID = "MillVib-Valve-v1"


def student_env_kwargs(preview=DEFAULT_PREVIEW, base: str = "pid-pf-robust", range_v: float = 10.0,
                       history=(), loop_sample: str = "previous", gauge: str | dict = "exact", filters=()) -> dict:
    """The student's environment (`control.preview.preview_env_kwargs`): a residual of +-`range_v` on `base`, the
    load cells, the preview, (where `history` names lags) the measured channels' history, and the loop's sample it
    reads (`observation.loop_sample`)."""
    return preview_env_kwargs(preview, range_v=range_v, base=base, history=history, loop_sample=loop_sample,
                              gauge=gauge, filters=filters)


def _rollout(student, teacher, env_id: str, env_kwargs: dict, task: Task, seeds: list[int], stats, progress=None,
             baseline=None):
    """Run the student (None: the zero action) on `seeds`; return observations and teacher labels: the residual
    that makes the loop's command the teacher's, or (with a `baseline` oracle) the teacher's command less the
    baseline's, both computed from the same state."""
    import torch

    venv = EpisodeBatch(env_id, len(seeds), **resolve_named_gains_for({"config": task.config, **env_kwargs},
                                                                      task, version="v1"))
    core = venv.core
    obs = venv.reset(seeds)
    for oracle in (teacher, baseline):
        if oracle is not None:
            oracle.attach(core, as_teacher=True)
            oracle.on_reset(venv.reset_infos, range(len(seeds)))
    xs, ys = [], []
    u_range = core.settings.u_range
    for _ in range(core.settings.max_steps):
        u_t = teacher.teacher_commands()
        u_b = None if baseline is None else baseline.teacher_commands()
        if student is None:
            action = np.zeros((core.settings.n, 1), dtype=np.float32)
        else:
            with torch.no_grad():
                x = torch.as_tensor(stats.normalize(obs))
                action = student(x).clamp(-1.0, 1.0).numpy()
        xs.append(obs.copy())
        obs, dones, infos = venv.step(action)
        # the digital PID's own command at the sample just taken, and the classical feedforward under the residual
        # (`actions.residual_feedforward`; zero without one), from the observation the action was taken on
        u_pid = core.loop_command()
        ys.append(np.clip((u_t - (u_pid if u_b is None else u_b)) / u_range, -1.0, 1.0)[:, None])
        teacher.on_step(infos)
        if progress is not None:
            progress.update(core.settings.n)
        if dones.all():
            break
    return np.concatenate(xs).astype(np.float32), np.concatenate(ys).astype(np.float32)


class _Pool:
    """DAgger's pooled samples in buffers that grow in place (no copy of the whole pool at each iteration), and
    its normalised observations in one reused buffer. `stats` gives numpy's ``mean(0)`` and ``var(0)`` of the
    float32 pool, the same numbers (rows summed in order, as numpy sums a C-ordered array along its first axis, a
    block at a time with the running sum as the block's first row), without the pool-sized temporaries."""

    _BLOCK = 65536

    def __init__(self, rows: int):
        self.rows, self.n = max(1, int(rows)), 0
        self.X: np.ndarray = np.empty((0, 0), np.float32)
        self.Y: np.ndarray = np.empty((0, 0), np.float32)
        self.Xn: np.ndarray = np.empty((0, 0), np.float32)

    def add(self, X: np.ndarray, Y: np.ndarray) -> None:
        if self.n + len(X) > len(self.X):  # the first rollout, or one longer than `rows` foresaw
            size = max(self.rows, 2 * len(self.X), self.n + len(X))
            grown = [np.empty((size,) + a.shape[1:], np.float32) for a in (X, Y)]
            if self.n:
                grown[0][:self.n], grown[1][:self.n] = self.X[:self.n], self.Y[:self.n]
            self.X, self.Y = grown
            self.Xn = np.empty_like(self.X)
        self.X[self.n:self.n + len(X)], self.Y[self.n:self.n + len(Y)] = X, Y
        self.n += len(X)

    def _sum(self, f) -> np.ndarray:
        buf = np.empty((self._BLOCK + 1, self.X.shape[1]), np.float32)
        total = np.zeros(self.X.shape[1], np.float32)
        for a in range(0, self.n, self._BLOCK):
            k = min(self._BLOCK, self.n - a)
            buf[0] = total
            f(self.X[a:a + k], buf[1:k + 1])
            total = buf[:k + 1].sum(axis=0)
        return total

    def stats(self) -> ObsStats:
        """VecNormalize's statistics of the pool (clip 10, epsilon 1e-8, as the shipped agents')."""
        mean = np.true_divide(self._sum(lambda x, out: np.copyto(out, x)), self.n, dtype=np.float32)

        def squares(x, out):
            np.subtract(x, mean, out=out)
            np.multiply(out, out, out=out)
        var = np.true_divide(self._sum(squares), self.n, dtype=np.float32)
        return ObsStats(mean.astype(np.float64), var.astype(np.float64), float(self.n), 10.0, 1e-8)

    def normalized(self, stats: ObsStats) -> tuple[np.ndarray, np.ndarray]:
        """The pool's observations normalised by `stats` (a view of the reused buffer) and its labels."""
        return stats.normalize(self.X[:self.n], out=self.Xn[:self.n]), self.Y[:self.n]


def _fit(model, X: np.ndarray, Y: np.ndarray, stats, epochs: int, seed: int, per_epoch: int | None = None,
         lr: float = 1e-3, batch: int = 1024, normalized: bool = False) -> float:
    """Least squares of the PPO actor's mean action on (X, Y); returns the final mean squared error. An epoch is a
    pass over all of (X, Y), or (`per_epoch`) that many samples drawn from it, in batches of at most `batch`: the draws
    run through shuffles of the whole pool, one after another, so every sample is drawn before any is drawn again
    (a shuffle's last batch may be short). `normalized`: X is already normalised by `stats`."""
    import torch

    policy = model.policy
    params = list(policy.mlp_extractor.policy_net.parameters()) + list(policy.action_net.parameters())
    opt = torch.optim.Adam(params, lr=lr)
    gen = torch.Generator().manual_seed(seed)
    Xt = torch.as_tensor(X if normalized else stats.normalize(X))
    Yt = torch.as_tensor(Y)
    n = Xt.shape[0]
    per_epoch = n if per_epoch is None else min(per_epoch, n)
    order, at = torch.randperm(n, generator=gen), 0
    for _ in range(epochs):
        left = per_epoch
        while left > 0:
            if at >= n:  # the next shuffle of the pool
                order, at = torch.randperm(n, generator=gen), 0
            size = min(batch, left, n - at)  # a shuffle's last batch may be short
            idx = order[at:at + size]
            at += size
            left -= size
            pred = policy.action_net(policy.mlp_extractor.policy_net(Xt[idx]))
            loss = torch.mean((pred - Yt[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        return float(torch.mean((policy.action_net(policy.mlp_extractor.policy_net(Xt)) - Yt) ** 2))


def _say(bar, what: str) -> None:
    """What the run does between its rollouts, beside the progress bar (its steps are the rollouts' alone)."""
    if bar is not None:
        bar.set_postfix_str(what)


@takes_task()
def distill(task: str | Task = "rolling", *, teacher: str = "mpc-preview", baseline: str | None = None, seed: int = 0,
            iterations: int = 4,
            episodes: int = 25, epochs: int = 30, preview=DEFAULT_PREVIEW, save_dir: str | Path,
            net: tuple = (256, 256), range_v: float = 100.0, history=DEFAULT_HISTORY,
            loop_sample: str = DEFAULT_LOOP_SAMPLE, progress: bool = True, command: str | None = None,
            validation_episodes: int = N_VALIDATION, preview_gauge: str = "measured", on: str | None = None,
            budget: str = "iteration", filters=(), validate_from: int = 1, batch: int = 1024,
            resume: bool = False) -> dict:
    """Teach a residual valve policy by `teacher` on `task` (module docstring); write the agent folder
    `save_dir` (model.zip, vecnormalize.npz, card.json) and return its card. Each iteration's student is scored
    on the first `validation_episodes` of the task's validation plants (default 40, as the shipped agents'). The
    student reads the preview as `preview_gauge` says (`envs.gauge`): "measured" (the default, as the benchmark
    gives it) or "exact" (the shipped students'); the card's env_kwargs say which. `filters`: time constants
    (loop samples) of the measured channels' moving averages the student also reads (`observation.history_filters`;
    none by default: on the varied mill they made the student dearer, docs/limitations.md).

    `on`: the classical controller the residual sits on, None for the reference's PID alone, or "pid-pf-preview"
    (the classical controller of the student's own information: its PID and, as the environment's
    ``actions.residual_feedforward``, its tuned feedforward on the task; iteration 0 is then that controller, and
    the student learns only what it misses, within +-`range_v`).

    `budget`: the fit's size at each iteration. "pool": `epochs` passes over all the pooled samples (the fit's cost
    grows with every iteration), Adam's step 1e-3; "iteration": `epochs` passes' worth of one iteration's samples,
    drawn from the whole pool, with Adam's step 1e-3 / sqrt(k) at iteration k (the network, warm from the last
    iteration, is refitted at a constant cost and moves less as the pool grows; the default). The two compared on
    the varied mill: docs/performance.md ("The distillation's fit budget"). `batch`: the fit's batch of samples.

    `validate_from`: the students of iterations `validate_from`.. are scored and the best of them is shipped; the
    earlier ones are not candidates (in every student shipped so far the best came at iteration 11 or later).

    The run keeps its work after each iteration in a journal beside `save_dir` (`training.distill_journal`:
    `save_dir` with `.partial` added); `resume` goes on from the last iteration an unfinished run of the same
    options finished there, to the same agent."""
    assert isinstance(task, Task)  # a name was resolved by @takes_task
    t = task
    seed = integer("seed", seed, lo=0, hi=49)
    iterations = integer("iterations", iterations, lo=1, hi=20)
    episodes = integer("episodes", episodes, lo=1, hi=TRAIN_SEED_STRIDE)
    epochs = integer("epochs", epochs, lo=1, hi=1000)
    validation_episodes = integer("validation_episodes", validation_episodes, lo=1, hi=len(t.seeds["validation"]))
    validate_from = integer("validate_from", validate_from, lo=1, hi=iterations)
    batch = integer("batch", batch, lo=1, hi=1 << 20)
    import torch

    torch.set_num_threads(1)  # as `train` and `finetune`: the student does not depend on the machine's core count
    torch.manual_seed(seed)
    if budget not in ("pool", "iteration"):
        raise ValueError(f"budget = {budget!r} is invalid: 'pool' or 'iteration'")
    range_v = real("range_v", range_v, lo=0.0, lo_open=True, hi=100.0)
    layers = [integer(f"net[{i}]", n, lo=1, hi=4096) for i, n in enumerate(net)]
    if preview_gauge not in ("measured", "exact"):
        raise ValueError(f"preview_gauge = {preview_gauge!r} is invalid: 'measured' or 'exact'")
    kwargs = _student_kwargs(t, preview, range_v, history, loop_sample, preview_gauge, on, filters)
    run = _Run(t, seed, episodes, epochs, budget, validation_episodes,
               _card_maker(t, kwargs, seed, teacher, episodes, epochs, command, baseline, on, budget, batch),
               load_controller(teacher, t, version="v1"),
               None if baseline is None else load_controller(baseline, t, version="v1"))
    identity = {"task": t.name, "teacher": teacher, "baseline": baseline, "on": on, "seed": seed,
                "iterations": iterations, "episodes": episodes, "epochs": epochs, "budget": budget, "batch": batch,
                "net": layers, "validation_episodes": validation_episodes, "validate_from": validate_from,
                "env_kwargs": kwargs}
    journal = open_distill_journal(save_dir, json.loads(json.dumps(identity)), iterations, resume)
    run.validate_from, run.batch, run.iterations = validate_from, batch, iterations
    try:
        card = _iterate(run, journal, kwargs, layers, progress, teacher, save_dir)
    except BaseException:
        journal.abandon()
        raise
    journal.close()
    return card


def _iterate(run: "_Run", journal, kwargs: dict, layers: list[int], progress: bool, teacher: str, save_dir) -> dict:
    """The run's iterations from the journal's last finished one, each kept in the journal but the last; the best
    student written as the agent folder `save_dir`. Returns its card."""
    import shutil

    iterations = run.iterations
    model, bar = run.start(kwargs, layers, iterations, progress, teacher)
    start = time.time()
    if journal.done:
        run.restore(journal, model, bar)
        start -= journal.wall_time_s
    for it in range(journal.done, iterations):
        X, Y = run.iteration(it, model, kwargs, journal.path, bar)
        if it + 1 < iterations:  # the last one's work goes into the agent folder itself
            journal.record(it, X, Y, model.policy, run.history, None if run.best is None else run.best[2],
                           time.time() - start)
    if bar is not None:
        bar.close()
    card = run.final_card(save_dir, start)
    with atomic_folder(Path(save_dir)) as tmp:
        for name in ("model.zip", "vecnormalize.npz", "card.json"):
            shutil.copyfile(run.best[0] / name, tmp / name)
    return card


def _student_kwargs(t: Task, preview, range_v: float, history, loop_sample: str, preview_gauge: str,
                    on: str | None, filters=()) -> dict:
    """The student's environment's keyword arguments; on a classical preview controller (`on`), its PID under the
    residual and its tuned feedforward as the environment's ``actions.residual_feedforward``."""
    kwargs = student_env_kwargs(preview, range_v=range_v, history=history, loop_sample=loop_sample,
                                gauge=preview_gauge, filters=filters)
    if on is not None:
        base = load_controller(on, t, version="v1")
        if not hasattr(base, "feedforward_gains"):
            raise ValueError(f"on = {on!r} is invalid: a classical preview controller ('pid-pf-preview') or None")
        kwargs["actions"] = {**kwargs["actions"], "residual_gains": list(base.env_kwargs["actions"]["residual_gains"]),
                             "residual_feedforward": base.feedforward_gains()}
    return kwargs


def _card_maker(t: Task, kwargs: dict, seed: int, teacher: str, episodes: int, epochs: int, command, baseline, on,
                budget: str, batch: int = 1024):
    """card(iteration, samples, mse): the card of the student of an iteration; its env_kwargs name the task's
    config, so that the card alone rebuilds the environment (the plain SB3 recipe)."""
    card_kwargs = {"config": t.config, **kwargs}

    def card(iteration: int, samples: int, mse: float) -> dict:
        return _card(t.name, ENV_ID, card_kwargs, seed, teacher, iteration, episodes, epochs, samples, mse, command,
                     baseline, on, budget, batch)
    return card


class _Run:
    """One distillation's iterations: the pool of labelled samples, each iteration's validation and the best."""

    def __init__(self, t: Task, seed: int, episodes: int, epochs: int, budget: str, validation_episodes: int,
                 card, teacher, baseline):
        self.t, self.seed, self.episodes, self.epochs, self.budget = t, seed, episodes, epochs, budget
        self.validation_episodes, self.card, self.teacher, self.baseline = validation_episodes, card, teacher, baseline
        self.pool: _Pool | None = None
        self.student: Any = None
        self.stats: ObsStats | None = None
        self.history: list[dict] = []
        self.best: Any = None
        #: the first iteration whose student is scored (and may be shipped), and the fit's batch
        self.validate_from = 1
        self.batch = 1024
        self.iterations = 1

    def start(self, kwargs: dict, layers: list[int], iterations: int, progress: bool, teacher: str):
        """The student's SB3 PPO model (its actor is the student) and the progress bar (None: none)."""
        import gymnasium as gym
        from stable_baselines3 import PPO

        env = gym.make(ENV_ID, config=self.t.config, **kwargs)
        model = PPO("MlpPolicy", env, seed=self.seed, device="cpu", verbose=0,
                    policy_kwargs=dict(log_std_init=-3.0, net_arch=dict(pi=list(layers), vf=[64, 64])))
        bar = None
        if progress:
            from tqdm.auto import tqdm
            unwrapped: Any = env.unwrapped  # a millvib env: its core (envs.core.MillVibCore) knows the episode
            bar = tqdm(total=iterations * self.episodes * unwrapped.core.settings.max_steps, unit="step",
                       desc=f"distill {teacher} on {self.t.name}")
        return model, bar

    def iteration(self, it: int, model, kwargs: dict, work: Path, bar) -> tuple[np.ndarray, np.ndarray]:
        """DAgger's iteration `it`: roll the student out (labels by the teacher), pool, refit, validate."""
        t, episodes = self.t, self.episodes
        # the seed's training plants in turn; past its 100, they come round again (the same plant and disturbances,
        # the new student's states: DAgger's next visit)
        first = t.train_env_seed(self.seed)
        seeds = [first + (it * episodes + j) % TRAIN_SEED_STRIDE for j in range(episodes)]
        X, Y = _rollout(self.student, self.teacher, ENV_ID, kwargs, t, seeds, self.stats, bar, self.baseline)
        if self.pool is None:  # room for every iteration's samples, if each is as long as the first
            self.pool = _Pool(len(X) * self.iterations)
        self.pool.add(X, Y)
        _say(bar, f"iteration {it + 1}: fitting the student to {self.pool.n} samples")
        stats = self.stats = self.pool.stats()
        Xc, Yc = self.pool.normalized(stats)
        if self.budget == "pool":
            mse = _fit(model, Xc, Yc, stats, self.epochs, self.seed + it, batch=self.batch, normalized=True)
        else:  # one iteration's worth of samples an epoch, and a step that shrinks as the pool grows
            mse = _fit(model, Xc, Yc, stats, self.epochs, self.seed + it, per_epoch=len(Y), lr=1e-3 / np.sqrt(it + 1),
                       batch=self.batch, normalized=True)
        policy = model.policy
        self.student = lambda x, p=policy: p.action_net(p.mlp_extractor.policy_net(x))
        if it + 1 < self.validate_from:  # not a candidate: its fit is recorded, not its score
            self.history.append({"iteration": it + 1, "samples": int(len(Yc)), "fit_mse": mse})
            _say(bar, f"iteration {it + 1}: fitted (students are scored from iteration {self.validate_from} on)")
            return X, Y
        folder = work / f"it{it + 1}"
        _write_agent(folder, model, stats, {})
        val_first = t.seeds["validation"].start
        _say(bar, f"iteration {it + 1}: scoring it on validation plants {val_first}-"
                  f"{val_first + self.validation_episodes - 1}")
        val = validation_result(folder, self.card(it + 1, len(Yc), mse), episodes=self.validation_episodes)
        self.history.append({"iteration": it + 1, "samples": int(len(Yc)), "fit_mse": mse, **val})
        if self.best is None or val["cost_mean"] < self.best[1]["cost_mean"]:
            self.best = (folder, val, it + 1)
        _say(bar, f"iteration {it + 1}: cost {val['cost_mean']:.4g}; best {self.best[1]['cost_mean']:.4g} "
                  f"(iteration {self.best[2]})")
        return X, Y

    def restore(self, journal, model, bar) -> None:
        """The run as it stood after the journal's last finished iteration: the pool rebuilt from its samples in
        order, the student's weights, the statistics of the pool, the iterations' records and the best so far."""
        for X, Y in journal.samples():
            if self.pool is None:
                self.pool = _Pool(len(X) * self.iterations)
            self.pool.add(X, Y)
        assert self.pool is not None  # a journal keeps at least one iteration
        journal.load_weights(model.policy)
        self.stats = self.pool.stats()
        policy = model.policy
        self.student = lambda x, p=policy: p.action_net(p.mlp_extractor.policy_net(x))
        self.history = list(journal.history)
        if journal.best is not None:
            record = self.history[journal.best - 1]
            val = {k: v for k, v in record.items() if k not in ("iteration", "samples", "fit_mse")}
            self.best = (journal.path / f"it{journal.best}", val, journal.best)
        if bar is not None:  # the finished iterations' rollouts
            bar.update(journal.done * (bar.total // self.iterations))
        _say(bar, f"iteration {journal.done}: resumed from {journal.path}")

    def final_card(self, save_dir, start: float) -> dict:
        """The best iteration's card, written into its folder: its validation, every iteration's, the run's time."""
        assert self.best is not None  # iterations >= 1: every iteration is validated
        folder, val, it = self.best
        card = self.card(it, self.history[it - 1]["samples"], self.history[it - 1]["fit_mse"])
        save_dir = Path(save_dir)
        card["name"] = save_dir.parent.name if save_dir.name.startswith("seed-") else save_dir.name
        card.update({"validation": val, "iterations": self.history, "wall_time_s": round(time.time() - start, 1),
                     "n_timesteps": int(self.history[it - 1]["samples"]),  # the loop samples its student was fitted on
                     "selected": {"iteration": it, "how": "the best validation cost among the iterations' students "
                                                          + (f"from iteration {self.validate_from} on "
                                                             if self.validate_from > 1 else "")
                                                          + "(iteration 0, the reference alone, never among them)"}})
        write_text_atomic(folder / "card.json", json.dumps(card, indent=2))
        return card


def _write_agent(folder: Path, model, stats, card: dict) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    model.save(folder / "model.zip")
    with open(folder / "vecnormalize.npz", "wb") as fh:
        np.savez(fh, mean=stats.mean, var=stats.var, count=np.float64(stats.count), clip_obs=np.float64(stats.clip_obs),
                 epsilon=np.float64(stats.epsilon))


def _card(task, env_id, kwargs, seed, teacher, iteration, episodes, epochs, samples, mse, command,
          baseline=None, on=None, budget="pool", batch=1024) -> dict:
    suffix = "" if task == "startup" else f"-{task}"
    name = f"dagger-on-{on}{suffix}" if on else f"dagger-residual-preview{suffix}"
    return {"name": name, **({"on": on} if on else {}), "algo": "ppo", "env_id": env_id, "task": task,
            "backend": "sb3", "env_kwargs": kwargs, "seed": seed, "normalize": "{'norm_obs': True}",
            "policy": "MlpPolicy (the actor of an SB3 PPO policy)",
            "trained_by": f"DAgger from {teacher}" + (f" less {baseline} (the label: what the teacher's knowledge "
                                                     "adds to the baseline oracle's command from the same state)"
                                                     if baseline else "")
                          + f": {iteration} iteration(s) of {episodes} training episodes, "
                          f"{samples} labelled loop samples pooled, {epochs} epochs of least squares (Adam, "
                          f"batch {batch}) per iteration"
                          + ("" if budget == "pool" else ", each epoch one iteration's worth of samples drawn from "
                                                         "the pool, step 1e-3/sqrt(iteration)")
                          + f"; final fit MSE {mse:.3g} (actions in [-1, 1])",
            "command": command or f"millvib distill --task {task} --seed {seed}"}
