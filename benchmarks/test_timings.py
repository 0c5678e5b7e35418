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


def _command(benchmark, args: list[str], rounds: int = 3) -> None:
    """`millvib ARGS` as a whole process, `rounds` times after a warm-up; its CPU seconds (every process it
    started, scripts/cpu_time.py) go into the result's extra_info."""
    cpu: list[float] = []

    def run() -> None:
        out = subprocess.run([sys.executable, str(CPU_TIME), *MILLVIB, *args], capture_output=True, text=True,
                             cwd=ROOT)
        assert out.returncode == 0, out.stderr[-2000:]
        found = re.search(r"([0-9.]+) CPU-s in its control group", out.stderr) or \
            re.search(r"wall, ([0-9.]+) CPU-s", out.stderr)
        assert found, out.stderr[-500:]
        cpu.append(float(found.group(1)))

    benchmark.pedantic(run, rounds=rounds, warmup_rounds=1, iterations=1)
    benchmark.extra_info["command"] = "millvib " + " ".join(args)
    benchmark.extra_info["cpu_s"] = cpu[1:]  # the counted rounds' (the first was the warm-up's)


@pytest.mark.benchmark(group="commands")
def test_main_job(benchmark):
    """The README's main job: the mission's question in one table."""
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
    from millvib_env.control.factory import load_controller

    ctrl = load_controller(name, "rolling", version="v1")
    venv = _batch(ctrl.env_id, 40)
    ctrl.attach(venv.core)
    ctrl.on_reset(venv.reset_infos, range(40))

    def samples() -> None:
        for _ in range(50):
            u = ctrl.teacher_commands()
            venv.step((u / venv.core.u_range)[:, None].astype(np.float32))

    benchmark.pedantic(samples, rounds=5, warmup_rounds=1)
    benchmark.extra_info["samples"] = 50 * 40


@pytest.mark.benchmark(group="pieces")
def test_student_actions(benchmark):
    """The rolling student's actions for 40 observations, 100 times (its network on one thread)."""
    from millvib_env.control.factory import load_controller

    ctrl = load_controller("dagger-on-pid-pf-preview-rolling", "rolling")
    obs = np.zeros((40, *ctrl.policy.observation_space.shape), dtype=np.float32)

    def act() -> None:
        for _ in range(100):
            ctrl.predict(obs)

    benchmark.pedantic(act, rounds=5, warmup_rounds=1)


@pytest.mark.benchmark(group="pieces")
def test_normalize_a_pool(benchmark):
    """A distillation's pool of 650 000 observations of 73 channels normalised (`ObsStats.normalize`)."""
    from millvib_env.control.normalization import ObsStats

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
    from millvib_env.control.agents import list_agents
    from millvib_env.control.registry import baseline_names

    return baseline_names("v1") + list_agents("rolling", "v1")


@pytest.mark.benchmark(group="rows")
@pytest.mark.parametrize("name", _rolling_rows())
def test_benchmark_row(benchmark, name):
    """Where a benchmark's time goes: one controller of the rolling task's default set on 8 held-out plants, in a
    warm process (an agent on its lowest training seed)."""
    from millvib_env.control.factory import load_controller
    from millvib_env.evaluation.evaluate import run_episodes
    from millvib_env.tasks import get_task

    task = get_task("rolling")
    plants = task.heldout_plants(8, 0)
    ctrl = load_controller(name, task, version="v1")
    benchmark.pedantic(run_episodes, args=(ctrl, plants), kwargs={"task": task, "env_id": ctrl.env_id}, rounds=3,
                       warmup_rounds=1)
    benchmark.extra_info["plants"] = len(plants)
