"""Where a benchmark's time goes: each controller of a task's default set alone, in one warm process, on the
same held-out plants (every seed of an agent), and what one call of an agent's `predict` costs against SB3's own.

    MILLVIB_NUM_THREADS=1 python scripts/benchmark_rows.py [--task rolling] [--episodes 8] [--env-version v1]

Wall seconds per controller (a warm-up run first: compilation, imports), then microseconds per call of the first
agent's deterministic actions (`control.agents.deterministic_actor`, what `AgentPolicy.predict` runs) and of
SB3's `model.predict`, on the same batch of `--episodes` normalised observations. The numbers are this machine's,
under whatever else it is doing: a benchmark, never a test.
"""
import argparse
import time

import numpy as np

from millvib_env.control.agents import agent_seeds, deterministic_actor, list_agents
from millvib_env.control.factory import load_controller
from millvib_env.control.registry import baseline_names
from millvib_env.evaluation.benchmark import run_benchmark


def per_call_us(fn, calls: int = 2000) -> float:
    fn()
    start = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - start) / calls * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="rolling")
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--env-version", default="v1")
    args = ap.parse_args()
    agents = list_agents(args.task, args.env_version)
    names = baseline_names(args.env_version) + agents
    kw = dict(task=args.task, episodes=args.episodes, progress=False, env_version=args.env_version, all_seeds=True)
    run_benchmark(["pid-robust"], reference="pid-robust", **kw)  # warm-up
    for name in names:
        start = time.perf_counter()
        run_benchmark([name], reference=name, **kw)
        seeds = len(agent_seeds(name)) if name in agents else 1
        print(f"{name:36s} seeds {seeds}  {time.perf_counter() - start:6.2f} s", flush=True)
    if agents:
        agent = load_controller(agents[0], args.task)
        shape = agent.policy.observation_space.shape
        obs = np.random.default_rng(0).standard_normal((args.episodes, *shape)).astype(np.float32)
        normalized = agent.normalize(obs)
        act = deterministic_actor(agent.policy)
        fast = per_call_us(lambda: act(normalized))
        sb3 = per_call_us(lambda: agent.model.predict(normalized, deterministic=True))
        norm = per_call_us(lambda: agent.normalize(obs))
        print(f"{agents[0]}, batch {args.episodes}: {fast:.0f} us a call (deterministic_actor) against {sb3:.0f} us "
              f"(SB3's model.predict); the observation's normalisation {norm:.0f} us beside either")


if __name__ == "__main__":
    main()
