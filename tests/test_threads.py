"""Threads: serial small batches, the knob, fork-based vectorisation after threads and torch."""
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import millvib_env
from millvib_env import threads


def test_small_batches_run_serially_and_the_knob_forces_serial(monkeypatch):
    assert not threads.use_threads(1) and not threads.use_threads(threads.MIN_PARALLEL - 1)
    monkeypatch.setenv(threads.THREADS_ENV, "1")
    assert not threads.use_threads(256)
    monkeypatch.setenv(threads.THREADS_ENV, "zero")
    with pytest.raises(ValueError, match="MILLVIB_NUM_THREADS"):
        threads.use_threads(256)


def test_serial_and_threaded_kernels_give_the_same_episodes(monkeypatch):
    def rollout():
        venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 16, seed=3, monitor=False)
        venv.reset()
        act = np.random.default_rng(0).uniform(-1, 1, (16, 3))
        return [venv.step(act)[0] for _ in range(5)]

    monkeypatch.setenv(threads.THREADS_ENV, "1")
    serial = rollout()
    monkeypatch.setenv(threads.THREADS_ENV, "2")
    threaded = rollout()
    assert all(np.array_equal(a, b) for a, b in zip(serial, threaded))


@pytest.mark.slow
def test_fork_vector_env_steps_after_the_parent_used_threads_and_torch():
    code = textwrap.dedent("""
        import numpy as np, torch, gymnasium as gym, millvib_env
        venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 16, seed=0)   # threaded kernel
        venv.reset(); venv.step(np.zeros((16, 3)))
        x = torch.randn(256, 256, requires_grad=True); (x @ x).sum().backward()  # torch's pool
        envs = gym.make_vec("MillVib-GainSchedule-v0", 2, vectorization_mode="async",
                            vector_kwargs={"context": "fork"})
        envs.reset(seed=0)
        obs, *_ = envs.step(np.zeros((2, 3)))
        assert np.all(np.isfinite(obs))
        envs.close()
        print("ok")
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240,
                         env={**__import__("os").environ, "MILLVIB_NUM_THREADS": "2"})
    assert run.returncode == 0 and "ok" in run.stdout, run.stderr[-2000:]
