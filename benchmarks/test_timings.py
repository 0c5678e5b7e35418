"""The project's timing suite (pytest-benchmark): what users wait for, as whole commands, and the pieces those
commands spend their time in. ``python scripts/timing_suite.py`` runs it on an idle machine and writes
docs/performance.md's table from its result, each figure with its command, the machine and the date.

Not part of the tests (`testpaths` is tests/): a timing is a measurement, never an assertion. The whole commands
run under scripts/cpu_time.py, which adds the CPU time of every process a command starts (worker processes
included) to pytest-benchmark's wall time; its interpreter's start (about 0.05 s) is in the wall time.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
CPU_TIME = ROOT / "scripts" / "cpu_time.py"
#: the `millvib` launcher, as its console script runs it (it sets the process defaults, one BLAS thread among
#: them, before numpy loads: `millvib_cli`)
MILLVIB = [sys.executable, "-c", "import sys; from millvib_cli import main; sys.exit(main())"]


def _command(benchmark, args: list[str], rounds: int = 3, *, launcher: list[str] | None = None, expect: int = 0,
             env: dict | None = None, cwd: Path = ROOT, shown: str | None = None, warmup: int = 1) -> None:
    """`millvib ARGS` (or `launcher` ARGS) as a whole process, `rounds` times after `warmup` rounds; its CPU
    seconds (every process it started, scripts/cpu_time.py) go into the result's extra_info. The process must exit
    with `expect`."""
    cpu: list[float] = []

    def run() -> None:
        out = subprocess.run([sys.executable, str(CPU_TIME), *(launcher or MILLVIB), *args], capture_output=True,
                             text=True, cwd=cwd, env=env)
        assert out.returncode == expect, out.stderr[-2000:]
        found = re.search(r"([0-9.]+) CPU-s in its control group", out.stderr) or \
            re.search(r"wall, ([0-9.]+) CPU-s", out.stderr)
        assert found, out.stderr[-500:]
        cpu.append(float(found.group(1)))

    benchmark.pedantic(run, rounds=rounds, warmup_rounds=warmup, iterations=1)
    benchmark.extra_info["command"] = shown or "millvib " + " ".join(args)
    benchmark.extra_info["cpu_s"] = cpu[warmup:]  # the counted rounds' (not the warm-up's)


@pytest.mark.benchmark(group="commands")
def test_main_job(benchmark):
    """The README's main job: the mission's question in one table, in one process."""
    _command(benchmark, ["benchmark", "--controllers", "answer", "--no-scenarios", "--jobs", "1", "--quiet"])


@pytest.mark.benchmark(group="commands")
def test_main_job_default_jobs(benchmark):
    """The same with the default `--jobs auto` (worker processes for the bound and the agent)."""
    _command(benchmark, ["benchmark", "--controllers", "answer", "--no-scenarios", "--quiet"])


@pytest.mark.benchmark(group="commands")
def test_main_job_with_scenarios(benchmark):
    _command(benchmark, ["benchmark", "--controllers", "answer", "--quiet"])


@pytest.mark.benchmark(group="commands")
def test_classical(benchmark):
    _command(benchmark, ["benchmark", "--controllers", "classical", "--quiet"])


@pytest.mark.benchmark(group="commands")
def test_headroom(benchmark):
    _command(benchmark, ["headroom", "--quiet"])


@pytest.mark.benchmark(group="commands")
def test_help(benchmark):
    _command(benchmark, ["--help"], rounds=5)


#: `millvib train` up to its first rollout: the child stops the process where PPO starts collecting
FIRST_ROLLOUT = """
import os, sys
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

def first_rollout(self, *args, **kwargs):
    os._exit(0)

OnPolicyAlgorithm.collect_rollouts = first_rollout
from millvib_cli import main
sys.argv = ["millvib"] + sys.argv[1:]
main()
"""


@pytest.mark.benchmark(group="commands")
def test_train_start(benchmark, tmp_path):
    """`millvib train --algo ppo` (the shipped configs/agents/ppo.yml) from the command to its first rollout:
    Python's start, the imports, the run folder, the environments and the model."""
    args = ["train", "--algo", "ppo", "--log-dir", str(tmp_path / "logs"), "--save-dir", str(tmp_path / "agent")]
    _command(benchmark, args, launcher=[sys.executable, "-c", FIRST_ROLLOUT], cwd=tmp_path,
             shown="millvib train --algo ppo, up to its first rollout")


#: damage -> a small damaged file's whole text (4-601 bytes), which every command must refuse in one line
DAMAGE = {
    "aliases": "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{n}: &{n} [{', '.join(['*' + p] * 9)}]\n" for p, n in zip("abcdefgh", "bcdefghi")),
    "a repeated key": "startup: {config: startup}\nstartup: {config: rolling}\n",
    "a 400-digit integer": "kp: " + "9" * 400 + "\n",
    "keys of mixed types": "{1: 2, zz: 3}\n",
    "broken YAML": "a: [1, 2\n",
    "a !!python tag": "!!python/object/apply:os.system ['true']\n",
    "nested 300 deep": "[" * 300 + "]" * 300 + "\n",
    "not UTF-8": b"\xff\xfe\x00\x01",
}
_BENCH = ["benchmark", "--controllers", "pid-robust", "--episodes", "2", "--no-scenarios", "--quiet"]
#: a file under configs/ -> a command that reads it
READERS = {
    "plant/paper.yaml": ["simulate", "--t-end", "0.2"],
    "severity.yaml": ["simulate", "--t-end", "0.2"],
    "tasks.yaml": ["tasks"],
    "env/startup.yaml": _BENCH,
    "control/v1/startup.yaml": _BENCH,
    "agents/ppo.yml": ["train", "--algo", "ppo", "--n-timesteps", "64", "--quiet"],
}


@pytest.mark.benchmark(group="refusals")
@pytest.mark.parametrize("name", list(READERS), ids=[n.replace("/", "-") for n in READERS])  # no path in an id
def test_refusal(benchmark, tmp_path, name):
    """How long a command takes to refuse a damaged config file, as a user meets it (a fresh `millvib` process,
    imports included, over a copy of configs/, `MILLVIB_CONFIGS`): the file replaced by each of `DAMAGE`'s
    damaged texts in turn, each once (docs/guarantees.md: no refusal takes more than 5 s; each exits 2 in one
    line, which the tests hold)."""
    import os
    import shutil

    root = tmp_path / "configs"
    shutil.copytree(ROOT / "configs", root)
    kinds = iter(DAMAGE.values())
    env = {**os.environ, "MILLVIB_CONFIGS": str(root)}

    def damage() -> None:
        text = next(kinds)
        (root / name).write_bytes(text if isinstance(text, bytes) else text.encode())

    def refuse() -> None:
        out = subprocess.run([*MILLVIB, *READERS[name]], capture_output=True, text=True, cwd=tmp_path, env=env)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr[-1000:]

    benchmark.pedantic(refuse, setup=damage, rounds=len(DAMAGE), iterations=1)
    benchmark.extra_info["command"] = f"millvib {' '.join(READERS[name])}, configs/{name} damaged " \
                                      f"({len(DAMAGE)} ways)"


#: damage -> a damaged agent card's whole text, which `millvib export` must refuse in one line
CARD_DAMAGE = {
    "not an object": "[1, 2]",
    "env_kwargs null": '{"name": "x", "algo": "ppo", "env_id": "MillVib-Valve-v1", "env_kwargs": null}',
    "seed 1e400": '{"name": "x", "algo": "ppo", "env_id": "MillVib-Valve-v1", "seed": 1e400}',
    "nested 300 deep": "[" * 300 + "]" * 300,
}


@pytest.mark.benchmark(group="refusals")
def test_refusal_card(benchmark, tmp_path):
    """`millvib export` of a shipped agent's folder whose card.json is replaced by each of `CARD_DAMAGE`'s texts in
    turn, each once: the card is checked as data before torch loads."""
    import shutil

    agent = tmp_path / "agent"
    shutil.copytree(ROOT / "agents" / "ppo-gain-pf" / "seed-0", agent)
    cards = iter(CARD_DAMAGE.values())
    args = ["export", str(agent), "--out", str(tmp_path / "a.onnx")]

    def refuse() -> None:
        out = subprocess.run([*MILLVIB, *args], capture_output=True, text=True, cwd=tmp_path)
        assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr[-1000:]

    def damage() -> None:
        (agent / "card.json").write_text(next(cards))

    benchmark.pedantic(refuse, setup=damage, rounds=len(CARD_DAMAGE), iterations=1)
    benchmark.extra_info["command"] = f"millvib export AGENT --out a.onnx, its card.json damaged ({len(CARD_DAMAGE)} " \
                                      "ways)"


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("env_id, kw, steps", [
    ("MillVib-Valve-v1", {"residual": True, "config": "rolling"}, 3000),
    ("MillVib-GainSchedule-v1", {"config": "rolling"}, 300),
    ("MillVib-Valve-v0", {}, 1500)], ids=["Valve-v1", "GainSchedule-v1", "Valve-v0"])
def test_one_env_step(benchmark, env_id, kw, steps):
    """One Gymnasium environment (``gym.make``) stepped with random actions in [-0.3, 0.3]: where Python's
    bookkeeping weighs most. The steps' hash (observations, rewards, flags, infos) goes into extra_info, so two
    versions of the code can be held to the same steps."""
    import hashlib
    import json

    import gymnasium as gym

    import millvib_env  # noqa: F401 - registers the ids

    env = gym.make(env_id, **kw)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.3, 0.3, (steps, *env.action_space.shape)).astype(np.float32)
    digest = hashlib.sha256()

    def run() -> None:
        env.reset(seed=5)
        for a in actions:
            obs, r, term, trunc, info = env.step(a)
            digest.update(np.ascontiguousarray(obs).tobytes() + np.float64(r).tobytes() + bytes([term, trunc]))
            digest.update(json.dumps({k: v for k, v in info.items() if k != "signals"}, sort_keys=True,
                                     default=str).encode())
            if term or trunc:
                env.reset()

    benchmark.pedantic(run, rounds=3, warmup_rounds=1)
    benchmark.extra_info["env_steps"] = steps
    benchmark.extra_info["steps_hash"] = digest.hexdigest()[:16]  # of the warm-up and the rounds, the same each


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("env_id", ["MillVib-Valve-v1", "MillVib-GainSchedule-v1"])
def test_kernel_share(benchmark, env_id, monkeypatch):
    """Where a batched step's time goes: 64 environments of the rolling task (a residual valve), 100 steps of random
    actions, the compiled loop kernel (`loop.kernel.advance_loop_batch`, which threads could share) against the
    rest (observation, reward, episode ends: serial Python). With a kernel K and a rest R per step, threads give
    at most (K + R) / (K / n + R)."""
    import time

    from millvib_env.envs import core
    from millvib_env.envs.batch import EpisodeBatch

    inner, spent = core.loop_kernel.advance_loop_batch, [0.0]

    def timed(*args):
        t = time.perf_counter()
        out = inner(*args)
        spent[0] += time.perf_counter() - t
        return out

    monkeypatch.setattr(core.loop_kernel, "advance_loop_batch", timed)
    kw = {"residual": True} if "Valve" in env_id else {}
    venv = EpisodeBatch(env_id, 64, config="rolling", **kw)
    venv.reset(list(range(500000, 500064)))
    a = np.random.default_rng(0).uniform(-0.3, 0.3, (100, 64, *venv.core.action_space.shape)).astype(np.float32)

    total = [0.0]

    def steps() -> None:
        t = time.perf_counter()
        for k in range(100):
            venv.step(a[k])
        total[0] += time.perf_counter() - t

    steps()  # warm
    spent[0] = total[0] = 0.0
    benchmark.pedantic(steps, rounds=5)
    benchmark.extra_info["env_steps"] = 100 * 64
    benchmark.extra_info["kernel_share"] = spent[0] / total[0]


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("algo, steps", [("ppo", 16384), ("sac", 8000)])
def test_train_steps(benchmark, tmp_path, algo, steps):
    """`train()` of the gain-schedule environment with the shipped hyperparameters (configs/agents/<algo>.yml) for
    a fixed number of environment steps, no evaluation or checkpoints: the learner's throughput, building the
    environments and the model included (SAC's first 5000 steps are its random warm-up, without updates)."""
    from millvib_env.training.train import train

    def run() -> None:
        train(algo, seed=0, n_timesteps=steps, log_dir=str(tmp_path / "logs"), eval_freq=10**9,
              checkpoint_freq=10**9, progress=False)

    benchmark.pedantic(run, rounds=2, warmup_rounds=1)
    benchmark.extra_info["env_steps"] = steps


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("sets", [1, 25])
def test_tuning_episodes(benchmark, sets):
    """What a tuning's evaluation costs an episode (`tuning.search.mean_costs`): `sets` fixed PID + pressure-feedback
    gain sets on the rolling task's 32 pid-robust tuning plants, in one batch (32 or 800 environments, as one search
    or the 25 grid plants of an oracle table in lockstep would run them). Equal rates say the batch's size buys
    nothing: the compiled kernel, per episode, is the cost."""
    from millvib_env.tasks import get_task
    from millvib_env.tuning.baselines import tuning_seeds
    from millvib_env.tuning.search import mean_costs

    task = get_task("rolling")
    seeds = tuning_seeds(task)["robust"]
    gains = np.repeat(np.array([[6.0, 8.0, 2.0, -4.0]]), sets, axis=0)  # log10 KP, KI, KD, KPL
    benchmark.pedantic(mean_costs, args=(gains, seeds), kwargs={"task": task}, rounds=3, warmup_rounds=1)
    benchmark.extra_info["episodes"] = sets * len(seeds)


@pytest.mark.benchmark(group="pieces")
def test_one_plant_second(benchmark):
    """One simulated second of the paper's nominal plant, the fast integrator (the engine under every env)."""
    from millvib_env.plant.integrate import simulate

    simulate(t_end=0.01)
    benchmark.pedantic(simulate, kwargs={"t_end": 1.0}, rounds=10, warmup_rounds=1)


def _batch(env_id: str, n: int, task: str = "rolling"):
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.tasks import get_task

    venv = EpisodeBatch(env_id, n, config=get_task(task).config)
    venv.reset(list(range(500000, 500000 + n)))
    return venv


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("env_id", ["MillVib-GainSchedule-v1", "MillVib-Valve-v1"])
def test_env_steps(benchmark, env_id):
    """100 steps of 64 environments of the rolling task (the batch a benchmark's row runs), zero actions."""
    venv = _batch(env_id, 64)
    action = np.zeros((64, *venv.core.action_space.shape), dtype=np.float32)

    def steps() -> None:
        for _ in range(100):
            venv.step(action)

    benchmark.pedantic(steps, rounds=5, warmup_rounds=1)
    benchmark.extra_info["env_steps"] = 100 * 64


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("name", ["mpc-oracle", "mpc-preview"])
def test_mpc_samples(benchmark, name):
    """50 loop samples of an MPC bound's commands for 40 plants of the rolling task (its QPs and predictions)."""
    from millvib_env.catalog.factory import load_controller

    ctrl = load_controller(name, "rolling", version="v1")
    venv = _batch(ctrl.env_id, 40)
    ctrl.attach(venv.core)
    ctrl.on_reset(venv.reset_infos, range(40))

    def samples() -> None:
        for _ in range(50):
            u = ctrl.teacher_commands()
            venv.step((u / venv.core.settings.u_range)[:, None].astype(np.float32))

    benchmark.pedantic(samples, rounds=5, warmup_rounds=1)
    benchmark.extra_info["samples"] = 50 * 40


@pytest.mark.benchmark(group="pieces")
def test_mpc_model_builds(benchmark):
    """100 builds of the start's `mpc-preview` model (linearisation, hold, condensed QP), one plant at set-points
    along the start's ramp: what the bound does every few samples there."""
    from millvib_env.catalog.factory import load_controller
    from millvib_env.control.mpc import mpc_model
    from millvib_env.params import MillParams

    settings = load_controller("mpc-preview", "startup", version="v1").settings
    params = MillParams()
    points = np.linspace(0.0, 1e-3, 100)

    def builds() -> None:
        for xd in points:
            mpc_model(params, settings, 5e-4, float(xd))

    benchmark.pedantic(builds, rounds=5, warmup_rounds=1)
    benchmark.extra_info["builds"] = 100


@pytest.mark.benchmark(group="pieces")
def test_student_actions(benchmark):
    """The rolling student's actions for 40 observations, 100 times (its network on one thread)."""
    from millvib_env.catalog.factory import load_controller

    ctrl = load_controller("dagger-on-pid-pf-preview-rolling", "rolling")
    obs = np.zeros((40, *ctrl.policy.observation_space.shape), dtype=np.float32)

    def act() -> None:
        for _ in range(100):
            ctrl.predict(obs)

    benchmark.pedantic(act, rounds=5, warmup_rounds=1)


@pytest.mark.benchmark(group="pieces")
def test_distill_fit_steps(benchmark):
    """100 Adam steps of a distillation's fit (`training.distill._fit`: batches of 1024 on the rolling student's
    256 x 256 network, 73 inputs, one torch thread), what a seed of `millvib distill --task rolling` spends two
    thirds of its time on (docs/performance.md)."""
    import torch

    from millvib_env.catalog.factory import load_controller
    from millvib_env.training.distill import _fit

    torch.set_num_threads(1)
    student = load_controller("dagger-on-pid-pf-preview-rolling", "rolling")
    rng = np.random.default_rng(0)
    X = rng.normal(size=(102400, student.policy.observation_space.shape[0])).astype(np.float32)
    Y = rng.uniform(-1, 1, size=(102400, 1)).astype(np.float32)
    benchmark.pedantic(_fit, args=(student.model, X, Y, student.obs_stats, 1, 0),
                       kwargs={"normalized": True}, rounds=3, warmup_rounds=1)
    benchmark.extra_info["samples"] = len(X)


@pytest.mark.benchmark(group="pieces")
def test_normalize_a_pool(benchmark):
    """A distillation's pool of 650 000 observations of 73 channels normalised (`ObsStats.normalize`)."""
    from millvib_env.catalog.normalization import ObsStats

    rng = np.random.default_rng(0)
    X = rng.normal(size=(650000, 73)).astype(np.float32)
    stats = ObsStats(X.mean(0).astype(np.float64), X.var(0).astype(np.float64), float(len(X)), 10.0, 1e-8)
    benchmark.pedantic(stats.normalize, args=(X,), rounds=5, warmup_rounds=1)


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("env_id", ["MillVib-Valve-v1", "MillVib-GainSchedule-v1"])
def test_render_frame(benchmark, env_id):
    """One `render()` frame (what RecordVideo pays per frame) after 25 more steps, the figure already built."""
    import gymnasium as gym

    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    env.render()  # the first frame builds the figure
    action = np.zeros(env.action_space.shape, np.float32)

    def steps() -> None:
        for _ in range(25):
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset(seed=0)

    benchmark.pedantic(env.render, setup=steps, rounds=10, warmup_rounds=1)
    env.close()


@pytest.mark.benchmark(group="pieces")
@pytest.mark.parametrize("transform", ["band_levels_rows", "vibration_severity_rows"])
def test_severity(benchmark, transform):
    """An episode's severity for 200 records: the bands over whole episodes (10 001 samples at 10 kHz) and the
    severity over their rest after 0.1 s (9 001 samples), one scipy thread, on random walks."""
    from millvib_env import severity

    records = np.cumsum(np.random.default_rng(1).normal(size=(200, 10_001)), axis=1) * 1e-3
    rows = records if transform == "band_levels_rows" else records[:, 1000:]
    benchmark.pedantic(getattr(severity, transform), args=(rows, 10_000.0), kwargs={"workers": 1}, rounds=5,
                       warmup_rounds=1)


@pytest.mark.benchmark(group="pieces")
def test_simulate_the_papers_cases(benchmark):
    """`simulate()` of the paper's nine cases, 1 s each (the fast integrator with its argument checks, packing and
    result object)."""
    from millvib_env.analysis.studies import PAPER_STUDIES
    from millvib_env.plant.integrate import simulate

    cases = [(c.params, c.gains) for s in PAPER_STUDIES for c in s.cases]

    def run() -> None:
        for p, g in cases:
            simulate(p, g, 1.0)

    benchmark.pedantic(run, rounds=5, warmup_rounds=1)


def _rolling_rows() -> list[str]:
    from millvib_env.catalog.agents import list_agents
    from millvib_env.catalog.registry import baseline_names

    return baseline_names("v1") + list_agents("rolling", "v1")


@pytest.mark.benchmark(group="rows")
@pytest.mark.parametrize("name", _rolling_rows())
def test_benchmark_row(benchmark, name):
    """Where a benchmark's time goes: one controller of the rolling task's default set on 8 held-out plants, in a
    warm process (an agent on its lowest training seed)."""
    from millvib_env.catalog.factory import load_controller
    from millvib_env.evaluation.evaluate import run_episodes
    from millvib_env.tasks import get_task

    task = get_task("rolling")
    plants = task.heldout_plants(8, 0)
    ctrl = load_controller(name, task, version="v1")
    benchmark.pedantic(run_episodes, args=(ctrl, plants), kwargs={"task": task, "env_id": ctrl.env_id}, rounds=3,
                       warmup_rounds=1)
    benchmark.extra_info["plants"] = len(plants)
