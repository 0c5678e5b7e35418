"""Seconds per `render()` frame over one episode (what RecordVideo pays per frame), zero actions, plant seed 0.

    MILLVIB_NUM_THREADS=1 python scripts/render_bench.py [ENV_ID ...]

Prints, per env id: the steps of the episode, the first frame (the figure is built) and the median and
largest of the others (rendered every 25 steps). Timings depend on the machine and its load.
"""
import statistics
import sys
import time

import gymnasium as gym
import numpy as np

import millvib_env  # noqa: F401 (registers the ids)


def frame_times(env_id: str) -> tuple[int, float, list[float]]:
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    start = time.perf_counter()
    env.render()
    first = time.perf_counter() - start
    times, n, done = [], 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, np.float32))
        n += 1
        done = terminated or truncated
        if n % 25 == 0:
            start = time.perf_counter()
            env.render()
            times.append(time.perf_counter() - start)
    env.close()
    return n, first, times


def main() -> None:
    for env_id in sys.argv[1:] or ["MillVib-Valve-v1", "MillVib-GainSchedule-v1"]:
        n, first, times = frame_times(env_id)
        print(f"{env_id}: {n} steps; first frame {first:.2f} s; others median {statistics.median(times):.3f} s, "
              f"max {max(times):.3f} s ({len(times)} frames)")


if __name__ == "__main__":
    main()
