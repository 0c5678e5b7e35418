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


def test_serial_and_threaded_batch_simulations_give_the_same_runs(monkeypatch):
    # the threaded batch deals the plants out in turn (thread j runs j, j + T, ...): 11 plants, shares unequal
    from millvib_env import MillParams, PIDGains
    from millvib_env.plant.integrate import simulate_batch

    params = [MillParams(c1=c) for c in np.geomspace(1.25e5, 2.25e6, 11)]
    gains = [PIDGains(kp, 1e-3) for kp in np.geomspace(1e5, 5e6, 11)]
    monkeypatch.setenv(threads.THREADS_ENV, "1")
    serial = simulate_batch(params, gains, 0.05)
    monkeypatch.setenv(threads.THREADS_ENV, "2")
    threaded = simulate_batch(params, gains, 0.05)
    assert np.array_equal(serial.states, threaded.states, equal_nan=True)
    assert np.array_equal(serial.n_steps, threaded.n_steps)


@pytest.mark.slow
def test_fork_vector_env_steps_after_the_parent_used_threads_and_torch():
    code = textwrap.dedent("""
        import sys
        import numpy as np, torch, gymnasium as gym, millvib_env
        venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 16, seed=0)   # threaded kernel
        venv.reset(); venv.step(np.zeros((16, 3)))
        # the registry lists the LQR and the MPC, whose solvers import these where they run, not with an env
        assert "scipy.optimize" not in sys.modules and "scipy.sparse" not in sys.modules
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


_POOL_SETTINGS = textwrap.dedent("""
    import os, sys
    assert "numba" not in sys.modules
    import millvib_env, numba
    from numba.np.ufunc import parallel
    policy = os.environ.get("OMP_WAIT_POLICY")
    started_before = parallel._is_initialized          # the pool must not exist yet when the policy is set
    print(policy, started_before, numba.config.THREADING_LAYER, numba.config.NUMBA_NUM_THREADS)
""")


def _pool_settings(**env) -> tuple[str, bool, str, int]:
    """In a fresh process that imports the package: the wait policy, whether numba's pool had started
    when it was set, the threading layer asked for and the thread count."""
    run = subprocess.run([sys.executable, "-c", _POOL_SETTINGS], capture_output=True, text=True, timeout=240,
                         env={**{k: v for k, v in __import__("os").environ.items() if k != "OMP_WAIT_POLICY"},
                              "MILLVIB_NUM_THREADS": "2", "NUMBA_NUM_THREADS": "2", **env})
    assert run.returncode == 0, run.stderr[-2000:]
    policy, started, layer, n = run.stdout.split()
    return policy, started == "True", layer, int(n)


def test_the_wait_policy_is_set_before_numbas_pool_starts_and_a_users_setting_is_kept():
    # that idle threads then sleep (0.001 s of CPU in a 0.5 s sleep, against 0.50 s when spinning) is a
    # timing, which depends on what else the machine runs: `python scripts/thread_bench.py --idle-cpu` measures it
    policy, started_before, layer, n = _pool_settings()
    assert policy == "PASSIVE" and not started_before and n == 2
    user_policy, started_before, _, _ = _pool_settings(OMP_WAIT_POLICY="ACTIVE")
    assert user_policy == "ACTIVE" and not started_before


def test_the_process_that_creates_a_versions_cache_says_once_that_it_compiles(tmp_path, monkeypatch, capsys):
    import numba

    from millvib_env import _numba_cache

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(numba.config, "CACHE_DIR", numba.config.CACHE_DIR)  # restored after the test
    for _ in range(2):
        _numba_cache.configure()
        monkeypatch.delenv("NUMBA_CACHE_DIR")
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "compile on first use" in lines[0] and str(tmp_path) in lines[0], lines
