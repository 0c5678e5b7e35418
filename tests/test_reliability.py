"""User errors end in one clear line; nothing silently wrong (issue: reliability)."""
import json
import os
import math
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import millvib_env
from millvib_env.cli import main as cli_main
from tests._fuzz import examples

WEIRD = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12),
                  st.floats(allow_nan=True, allow_infinity=True),
                  st.text(max_size=8), st.lists(st.floats(allow_nan=True), max_size=3),
                  st.dictionaries(st.text(max_size=5), st.floats(), max_size=2))


def test_the_fuzz_profile_lengthens_every_property_based_test(monkeypatch):
    """`tests._fuzz.examples`: a test's own count in the suite, at least the fuzz profile's under
    HYPOTHESIS_PROFILE=fuzz (a test's own max_examples would outrank the profile), MILLVIB_FUZZ_EXAMPLES exactly,
    and a bad count is one line."""
    monkeypatch.delenv("MILLVIB_FUZZ_EXAMPLES", raising=False)
    monkeypatch.delenv("HYPOTHESIS_PROFILE", raising=False)
    assert examples(60) == 60
    monkeypatch.setenv("HYPOTHESIS_PROFILE", "fuzz")
    assert examples(60) == settings.get_profile("fuzz").max_examples > 60
    monkeypatch.setenv("MILLVIB_FUZZ_EXAMPLES", "7")
    assert examples(60) == 7
    for bad in ("0", "-3", "x", "1e3"):
        monkeypatch.setenv("MILLVIB_FUZZ_EXAMPLES", bad)
        with pytest.raises(ValueError, match=f"MILLVIB_FUZZ_EXAMPLES = '{bad}' is invalid"):
            examples(60)


@settings(max_examples=examples(60), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(["x0", "params", "scenario", "bogus"]), value=WEIRD)
def test_fuzzed_reset_options_raise_valueerror_or_give_finite_observations(key, value):
    env = gym.make("MillVib-GainSchedule-v0").unwrapped
    try:
        obs, _ = env.reset(seed=0, options={key: value})
    except ValueError as err:
        assert "\n" not in str(err)
        return
    _, reward, *_ = env.step(np.zeros(3))
    assert np.all(np.isfinite(obs)) and math.isfinite(reward)


ENV_KWARG_KEYS = ["episode_s", "observe_params", "residual", "reward", "envelope", "initial", "actions",
                  "disturbances", "randomize", "config", "plant", "sample_rate_hz"]


@settings(max_examples=examples(80), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(ENV_KWARG_KEYS), value=WEIRD)
@example(key="config", value="\n")  # found by the fuzz (seed 20261205): the missing file's path, shown as it was,
@example(key="plant", value="\n")   # broke the line
def test_fuzzed_env_kwargs_raise_valueerror_or_give_finite_rollouts(key, value):
    try:
        venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 2, seed=0, **{key: value})
    except ValueError as err:
        assert "\n" not in str(err)
        return
    obs = venv.reset()
    for _ in range(3):
        obs, rew, _, _ = venv.step(np.zeros((2, 3)))
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rew))


#: an action as a client might send it by mistake: any number (an integer beyond a float's too), a string, None, a
#: list of them of any length, or an array of any shape
ACTION = st.one_of(WEIRD, st.just(10 ** 400),
                   st.lists(st.one_of(st.floats(allow_nan=True), st.integers(-10 ** 400, 10 ** 400)), max_size=4),
                   st.builds(lambda r, c, v: np.full((r, c), v), st.integers(0, 3), st.integers(0, 4),
                             st.floats(-1e3, 1e3)))
_ACTION_ENVS: dict = {}


@settings(max_examples=examples(60), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(env_id=st.sampled_from(["MillVib-GainSchedule-v1", "MillVib-Valve-v1", "MillVib-Valve-v0"]), action=ACTION)
@example(env_id="MillVib-Valve-v1", action=[10 ** 400])  # found by a fuzz: it ended in an OverflowError
def test_fuzzed_actions_raise_valueerror_or_give_finite_steps(env_id, action):
    """Whatever a client sends as an action: a finite step (an action of the right shape, clipped to the box) or
    a ValueError of one line, and the episode goes on after it."""
    env = _ACTION_ENVS.get(env_id)
    if env is None:
        env = _ACTION_ENVS[env_id] = gym.make(env_id)
        env.reset(seed=0)
    try:
        obs, reward, terminated, truncated, _ = env.step(action)
    except ValueError as err:
        assert "\n" not in str(err)
        obs, reward, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
    assert np.all(np.isfinite(obs)) and math.isfinite(reward)
    if terminated or truncated:
        env.reset(seed=0)


def test_a_refused_array_is_shown_on_one_line():
    """An error names the value it refuses by its repr, and numpy breaks an array's repr over lines: a user's hook
    given as an array, or returning one, is still refused in one line (found by a fuzz of the hooks)."""
    grid = np.ones((2, 2))
    for kwargs in ({"reward_fn": grid}, {"envelope_fn": grid}, {"base_controller": grid},
                   {"extra_disturbances": grid}, {"reward_fn": lambda terms: grid}):
        with pytest.raises(ValueError) as err:
            env = gym.make("MillVib-GainSchedule-v1", **kwargs)
            env.reset(seed=0)
            env.step(np.zeros(env.action_space.shape))
        assert "\n" not in str(err.value) and "array([[1., 1.], [1., 1.]])" in str(err.value), (kwargs, err.value)


def test_nan_and_string_booleans_are_refused():
    with pytest.raises(ValueError, match="x0"):
        gym.make("MillVib-GainSchedule-v0").reset(options={"x0": float("nan")})
    with pytest.raises(ValueError, match="initial.x0_m"):
        millvib_env.make_vec_env("MillVib-GainSchedule-v0", 1, initial={"x0_m": float("nan")})
    with pytest.raises(ValueError, match="envelope.x_max_m"):
        millvib_env.make_vec_env("MillVib-GainSchedule-v0", 1, envelope={"x_max_m": float("nan")})
    with pytest.raises(ValueError, match="observe_params"):
        gym.make("MillVib-GainSchedule-v0", observe_params="no")


def test_stepping_an_ended_or_unstarted_episode_says_to_reset():
    env = gym.make("MillVib-GainSchedule-v0").unwrapped
    with pytest.raises(ValueError, match="reset"):
        env.step(np.zeros(3))
    env.reset(seed=0)
    done = False
    while not done:
        _, _, term, trunc, _ = env.step(np.zeros(3))
        done = term or trunc
    with pytest.raises(ValueError, match="reset"):
        env.step(np.zeros(3))


def test_a_batch_too_large_for_memory_is_refused_before_allocating():
    with pytest.raises(ValueError, match="GiB"):
        millvib_env.make_vec_env("MillVib-Valve-v0", 10**6)


@pytest.mark.parametrize("argv, match", [
    (["benchmark", "--episodes", "0"], "--episodes"),
    (["benchmark", "--task", "nope"], "task 'nope'"),
    (["benchmark", "--controllers", "no-such-agent"], "no-such-agent"),
    (["benchmark", "--seed", "-1"], "--seed"),
    (["benchmark", "--episodes", "abc"], "--episodes"),
    (["benchmark", "--jobs", "0"], "--jobs: '0' is invalid: a whole number from 1 to 1024, or auto"),
    (["benchmark", "--json", "/proc/version/x.json"], "--json"),
    (["train", "--algo", "ppo", "--n-timesteps", "0"], "--n-timesteps"),
    (["train", "--algo", "ppo", "--validation-episodes", "0"], "--validation-episodes"),
    (["train", "--algo", "ppo", "--validation-episodes", "1001"], "--validation-episodes = 1001 is invalid: a whole "
                                                                  "number in [1, 1000]"),
    (["train", "--algo", "ppo", "--task", "rolling", "--seed", "99"], "training seed 99"),
    (["simulate", "--set", "c1=abc"], "c1"),
    (["simulate", "--set", "c1=-1"], "c1"),
])
def test_bad_cli_input_exits_2_with_one_line(argv, match, capsys):
    assert _exit_status(argv + ["--quiet"] if argv[0] in ("benchmark", "train") else argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and match in err


def _exit_status(argv) -> int:
    try:
        return cli_main(argv)
    except SystemExit as exc:  # argparse's own refusals
        return exc.code


#: flag values a user may mistype: numbers out of range, not numbers, empty, paths that cannot be written
BAD_OR_ODD = ["0", "-1", "2", "1e9", "3.5", "nan", "inf", "abc", "", "99999999", "/proc/version/x", "rolling",
              "change", "pid-paper", "ppo-gain-pf", "x.onnx", "c1=abc", "c1=nan", "Ct=-1", "kp=1e99", "bogus=1",
              "line\nbreak", "a\tb.onnx"]
FUZZ_FLAGS = {
    # benchmark: a valid draw runs pid-paper on 2 plants; train: --n-timesteps is always invalid, so no run trains
    # benchmark and sweep: their figures are drawn by tests of their own (tests/_figures.py); here, the data only
    "benchmark": (["--controllers", "pid-paper", "--no-scenarios", "--episodes", "2", "--quiet", "--no-figures"],
                  ["--task", "--episodes", "--seed", "--controllers", "--json", "--out", "--env"]),
    "train": (["--algo", "ppo", "--quiet"], ["--algo", "--task", "--seed", "--jobs", "--eval-freq", "--env",
                                              "--n-eval-episodes", "--checkpoint-freq", "--config", "--save-dir",
                                              "--validation-episodes"]),
    "simulate": (["--t-end", "0.05"], ["--set", "--kp", "--ki", "--kd", "--t-end", "--x0", "--preset", "--method",
                                       "--csv"]),
    "sweep": (["--controllers", "pid-paper", "--plants", "2", "--quiet", "--no-figures"],
              ["--plants", "--params", "--task", "--seed", "--jobs", "--controllers"]),
}


@pytest.mark.slow  # a wide fuzz: 40 CLI runs
@settings(max_examples=examples(40), deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(command=st.sampled_from(sorted(FUZZ_FLAGS)), data=st.data())
def test_fuzzed_cli_arguments_exit_0_or_2_with_one_line(command, data, tmp_path_factory, capsys):
    base, flags = FUZZ_FLAGS[command]
    chosen = data.draw(st.lists(st.tuples(st.sampled_from(flags), st.sampled_from(BAD_OR_ODD)), min_size=1,
                                max_size=3))
    argv = [command, *base]
    for flag, value in chosen:
        argv += [flag, value]
    if command == "train":
        argv += ["--n-timesteps", data.draw(st.sampled_from(["0", "-3", "abc", "nan", ""]))]
    if command == "sweep":
        argv += ["--out", str(tmp_path_factory.mktemp("sweep") / "out")]
    capsys.readouterr()
    here = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("cwd"))  # relative output paths land in a temporary folder
    try:
        status = _exit_status(argv)
    finally:
        os.chdir(here)
    out = capsys.readouterr()
    assert status in (0, 2), (argv, out.err)
    assert "Traceback" not in out.err + out.out
    if status == 2:
        lines = out.err.strip().splitlines()
        assert len(lines) == 1 and "error" in lines[0], (argv, out.err)


@pytest.mark.parametrize("t_end", ["1e9", "99999999", "1e300"])
def test_a_huge_simulated_time_is_refused_before_allocation(t_end, capsys):
    # found by the randomized fuzz: `simulate --t-end 99999999` tried to allocate 7.28 TiB
    assert _exit_status(["simulate", "--t-end", t_end]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "t_end" in err[0]


def test_an_agent_folder_without_its_statistics_is_an_error(tmp_path):
    import shutil

    from millvib_env._paths import agents_dir
    from millvib_env.catalog.factory import load_controller

    folder = tmp_path / "agent"
    shutil.copytree(agents_dir() / "ppo-gain-pf" / "seed-0", folder)
    (folder / "vecnormalize.npz").unlink()
    with pytest.raises(ValueError, match="vecnormalize.npz is missing"):
        load_controller(str(folder))
    (folder / "vecnormalize.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a valid statistics file"):
        load_controller(str(folder))
    (folder / "card.json").write_text(json.dumps({"algo": "ppo"}))
    with pytest.raises(ValueError, match="card.json is not a valid model card"):
        load_controller(str(folder))


def test_a_changed_shipped_agent_fails_its_checksum(shipped_agents_copy):
    import shutil

    from millvib_env.catalog.factory import load_controller

    root = shipped_agents_copy
    card = root / "ppo-gain-pf" / "seed-0" / "card.json"
    card.write_text(card.read_text().replace('"seed": 0', '"seed": 1'))
    with pytest.raises(ValueError, match="does not match its checksum"):
        load_controller("ppo-gain-pf")
    (root / "ppo-gain-pf" / "seed-0" / "card.json").unlink()
    shutil.copytree(root / "ppo-gain-pf" / "seed-1", root / "ppo-gain-pf" / "seed-9")
    with pytest.raises(ValueError, match="seed-9 is not in"):
        load_controller("ppo-gain-pf", seed=9)  # an unlisted seed folder is not loaded silently


def test_import_and_help_work_whatever_the_config_files(tmp_path):
    env = {"MILLVIB_CONFIGS": str(tmp_path), "PATH": "/usr/bin:/bin"}
    code = "import millvib_env, sys; from millvib_env.cli import main; sys.exit(main(['--help']))"
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "millvib" in run.stdout


def test_written_files_respect_the_umask(tmp_path):
    import os

    from millvib_env._paths import write_text_atomic

    old = os.umask(0o022)
    try:
        path = write_text_atomic(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (path.stat().st_mode & 0o777) == 0o644


def test_an_interrupted_folder_write_leaves_the_old_folder_whole(tmp_path):
    from millvib_env._paths import atomic_folder

    out = tmp_path / "results"
    with atomic_folder(out) as tmp:
        (tmp / "a.txt").write_text("run 1")
    with pytest.raises(KeyboardInterrupt):
        with atomic_folder(out) as tmp:
            (tmp / "a.txt").write_text("run 2")
            (tmp / "b.txt").write_text("run 2")
            raise KeyboardInterrupt
    assert sorted(p.name for p in out.iterdir()) == ["a.txt"] and (out / "a.txt").read_text() == "run 1"
    assert [p.name for p in tmp_path.iterdir()] == ["results"]  # no temporary folder left behind


def test_the_same_benchmark_gives_the_same_json_bytes(tmp_path):
    paths = [tmp_path / "a.json", tmp_path / "b.json"]
    for p in paths:
        assert cli_main(["benchmark", "--controllers", "pid-paper", "pid-robust", "--episodes", "2", "--quiet",
                         "--no-scenarios", "--json", str(p)]) == 0
    assert paths[0].read_bytes() == paths[1].read_bytes()


@pytest.mark.slow
def test_resume_falls_back_to_the_last_intact_checkpoint_and_keeps_the_evaluations(tmp_path, capsys):
    from millvib_env.training.train import train
    from tests.test_training import EXTRA, QUICK_VALIDATION, TINY

    cfg = tmp_path / "ppo.yml"
    cfg.write_text(TINY.format(policy="MlpPolicy", extra=EXTRA["ppo"]))
    kw = dict(config=str(cfg), log_dir=str(tmp_path / "runs"), eval_freq=128, n_eval_episodes=2,
              checkpoint_freq=128, progress=False, validation_episodes=QUICK_VALIDATION)
    train("ppo", seed=2, **kw)
    ckpts = tmp_path / "runs" / "ppo_MillVib-GainSchedule-v1_s2" / "checkpoints"
    newest = max(ckpts.glob("rl_model_*_steps.zip"), key=lambda p: int(p.stem.split("_")[-2]))
    newest.write_bytes(newest.read_bytes()[:100])  # truncated by a killed run
    evals = tmp_path / "runs" / "ppo_MillVib-GainSchedule-v1_s2" / "eval" / "evaluations.npz"
    before = len(np.load(evals)["timesteps"])
    card = train("ppo", seed=2, n_timesteps=512, resume=True, **kw)
    assert "cannot be loaded" in capsys.readouterr().err
    assert card["n_timesteps"] >= 512
    assert len(np.load(evals)["timesteps"]) > before  # the history continued
