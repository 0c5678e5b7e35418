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


_IDLE_CPU = textwrap.dedent("""
    import os, sys, time
    assert "numba" not in sys.modules
    import numpy as np, millvib_env, numba
    from numba.np.ufunc import parallel
    policy = os.environ.get("OMP_WAIT_POLICY")
    started_before = parallel._is_initialized          # the pool must not exist yet when the policy is set
    venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 16, seed=0, monitor=False)
    venv.reset(); venv.step(np.zeros((16, 3)))         # a threaded batch: the pool starts here
    layer = numba.threading_layer()
    t0 = time.process_time(); time.sleep(0.5); idle = time.process_time() - t0   # CPU burnt while idle
    print(policy, started_before, layer, numba.get_num_threads(), f"{idle:.3f}")
""")


def _idle_cpu(**env) -> tuple[str, bool, str, int, float]:
    run = subprocess.run([sys.executable, "-c", _IDLE_CPU], capture_output=True, text=True, timeout=240,
                         env={**{k: v for k, v in __import__("os").environ.items() if k != "OMP_WAIT_POLICY"},
                              "MILLVIB_NUM_THREADS": "2", "NUMBA_NUM_THREADS": "2", **env})
    assert run.returncode == 0, run.stderr[-2000:]
    policy, started, layer, n, idle = run.stdout.split()
    return policy, started == "True", layer, int(n), float(idle)


@pytest.mark.slow
def test_idle_plant_threads_sleep_because_the_policy_is_set_before_the_pool_starts():
    policy, started_before, layer, n, idle = _idle_cpu()
    assert policy == "PASSIVE" and not started_before and n == 2
    if layer != "omp":
        pytest.skip(f"numba's threading layer here is {layer!r}, not OpenMP: the wait policy does not apply")
    # measured here: 0.001 s of CPU in a 0.5 s sleep; spinning threads burn 0.50 s (below)
    assert idle < 0.1
    user_policy, _, _, _, spinning = _idle_cpu(OMP_WAIT_POLICY="ACTIVE")  # a user's setting is kept ...
    assert user_policy == "ACTIVE" and spinning > 0.25  # ... and the measurement sees spinning threads
