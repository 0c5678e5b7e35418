"""rl-baselines3-zoo trains on our environments with our hyperparameter files, unchanged."""
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow
pytest.importorskip("rl_zoo3")

from millvib_env._paths import config_dir  # noqa: E402

G, V = "MillVib-GainSchedule-v0", "MillVib-Valve-v0"
CASES = [("ppo", "ppo.yml", "n_envs:2 n_steps:64 batch_size:64 n_epochs:1", G),
         ("sac", "sac.yml", "n_envs:2 learning_starts:64 batch_size:32 buffer_size:1000", G),
         ("ppo_lstm", "ppo_lstm.yml", "n_envs:2 n_steps:64 batch_size:64 n_epochs:1", G),
         # a residual on pid-pf-ff, named in the file: the environment resolves the name itself
         ("ppo", "pf/ppo.yml", "n_envs:2 n_steps:64 batch_size:64 n_epochs:1", V)]


@pytest.mark.parametrize("algo, file, small, env", CASES)
def test_the_zoo_trains_on_our_env_with_our_file(tmp_path, algo, file, small, env):
    cmd = [sys.executable, "-m", "rl_zoo3.train", "--algo", algo, "--env", env,
           "--gym-packages", "millvib_env", "--conf-file", str(config_dir() / "agents" / file), "-n", "256",
           "--eval-freq", "-1", "--log-folder", str(tmp_path), "--seed", "0", "--hyperparams", *small.split()]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    assert list(tmp_path.glob(f"{algo}/{env}_*/{env}.zip"))
