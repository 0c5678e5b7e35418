"""rl-baselines3-zoo trains on our environments with our hyperparameter files, unchanged.

The zoo's own entry point (`rl_zoo3.train.train`, what `python -m rl_zoo3.train` runs) is called in the
test process with the command line a user types: the same argument parsing, `--gym-packages` import and
hyperparameter file, without a new interpreter importing torch, the zoo and the package again for each
run (10 of its 11 CPU-seconds)."""
import sys

import pytest

pytestmark = pytest.mark.slow
pytest.importorskip("rl_zoo3")

from millvib_env._paths import config_dir  # noqa: E402

G, V, G0 = "MillVib-GainSchedule-v1", "MillVib-Valve-v1", "MillVib-GainSchedule-v0"
# ppo.yml on the gain-schedule env is trained by the recipe test below (one zoo run for both checks)
CASES = [("sac", "sac.yml", "n_envs:2 learning_starts:64 batch_size:32 buffer_size:1000", G),
         ("ppo_lstm", "ppo_lstm.yml", "n_envs:2 n_steps:64 batch_size:64 n_epochs:1", G0),
         # a residual on pid-pf-ff, named in the file: the environment resolves the name itself
         ("ppo", "pf/ppo.yml", "n_envs:2 n_steps:64 batch_size:64 n_epochs:1", V)]


def zoo_train(args, folder, monkeypatch):
    """`python -m rl_zoo3.train ARGS`, run in this process from `folder`."""
    from rl_zoo3.train import train

    monkeypatch.chdir(folder)
    monkeypatch.setattr(sys, "argv", ["rl_zoo3/train.py", *args])
    train()


@pytest.mark.parametrize("algo, file, small, env", CASES)
def test_the_zoo_trains_on_our_env_with_our_file(tmp_path, monkeypatch, algo, file, small, env):
    zoo_train(["--algo", algo, "--env", env, "--gym-packages", "millvib_env", "--conf-file",
               str(config_dir() / "agents" / file), "-n", "256", "--eval-freq", "-1", "--log-folder", str(tmp_path),
               "--seed", "0", "--hyperparams", *small.split()], tmp_path, monkeypatch)
    assert list(tmp_path.glob(f"{algo}/{env}_*/{env}.zip"))


def test_the_documented_task_recipe_keeps_the_files_training_reward(tmp_path, monkeypatch):
    # the zoo trains on our env with ppo.yml; its --env-kwargs replaces a file's env_kwargs: the recipe
    # (docs/scaling.md) restates them
    import yaml

    class ZooLoader(yaml.SafeLoader):  # the zoo saves an OrderedDict as a tagged list of pairs: read as data
        pass

    ZooLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict",
                              lambda loader, node: dict(loader.construct_sequence(node.value[0], deep=True)))

    zoo_train(["--algo", "ppo", "--env", G, "--gym-packages", "millvib_env",
               "--conf-file", str(config_dir() / "agents" / "ppo.yml"), "-n", "128", "--eval-freq", "-1",
               "--log-folder", str(tmp_path), "--seed", "0", "--hyperparams", "n_envs:2", "n_steps:64", "batch_size:64",
               "n_epochs:1", "--env-kwargs", "config:'rolling'", "reward:dict(w_vibration=2.0)"], tmp_path, monkeypatch)
    assert list(tmp_path.glob(f"ppo/{G}_*/{G}.zip"))
    saved = yaml.load(next(tmp_path.glob(f"ppo/{G}_*/{G}/config.yml")).read_text(), Loader=ZooLoader)
    env_kwargs = saved["env_kwargs"]
    file_kwargs = yaml.safe_load((config_dir() / "agents" / "ppo.yml").read_text())[G]["env_kwargs"]
    assert env_kwargs == {"config": "rolling", **file_kwargs}
