"""Controllers, agent training (smoke) and the benchmark."""
import importlib.metadata
import importlib.util
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from millvib_env.cli import main as cli_main
from millvib_env.catalog.agents import agent_seeds, list_agents
from millvib_env.catalog.factory import load_controller
from millvib_env.control.policies import FixedGainPolicy, OraclePolicy
from millvib_env.envs.config import load_env_config
from millvib_env.envs.core import MillVibCore
from millvib_env.params import PIDGains
from millvib_env.tasks import get_task
from millvib_env.evaluation.benchmark import public_json, run_benchmark
from millvib_env.evaluation.evaluate import run_episodes
from millvib_env.training.train import train
from tests._skips import skip_without_sbx

SCHEMA = {"severity_mean", "severity_median", "severity_p95", "tracking_rms_um_mean", "diverged_rate", "cost_mean",
          "episodes"}

TINY = """
MillVib-GainSchedule-v1:
  n_envs: 4
  n_timesteps: 256
  policy: {policy}
  normalize: "dict(norm_obs=True, norm_reward=True)"
{extra}
"""
#: the smoke trainings' model-card validation: a few of the task's validation plants (the shipped agents' 40 are
#: what a card reports; here the card is checked, not the agent)
QUICK_VALIDATION = 4
EXTRA = {
    "ppo": "  n_steps: 32\n  batch_size: 64\n  n_epochs: 1\n  policy_kwargs: \"dict(net_arch=[16])\"",
    "sac": "  learning_starts: 64\n  batch_size: 32\n  buffer_size: 1000\n  policy_kwargs: \"dict(net_arch=[16])\"",
    "recurrentppo": "  n_steps: 32\n  batch_size: 64\n  n_epochs: 1\n  policy_kwargs: \"dict(lstm_hidden_size=8)\"",
}


def test_fixed_gain_policy_runs_exactly_its_gains_even_outside_the_action_bounds():
    pol = FixedGainPolicy("x", PIDGains(3e5, 1e4, 10.0))
    cfg = load_env_config("default", **pol.env_kwargs)
    core = MillVibCore(1, "gain", cfg)
    action, _ = pol.predict(np.zeros((5, 8)))
    assert action.shape == (5, 3)
    assert np.array_equal(core.gains_from_action(action[0]), [3e5, 1e4, 10.0])  # exact, not to rounding
    big = FixedGainPolicy("y", [1e12, 1e-3, 0.0])  # beyond KP's 1e7 bound: run as given, not clipped
    core = MillVibCore(1, "gain", load_env_config("default", **big.env_kwargs))
    assert core.gains_from_action(big.predict(np.zeros(8))[0])[0] == 1e12


def test_oracle_needs_and_uses_the_true_parameters():
    oracle = load_controller("pid-oracle")
    assert isinstance(oracle, OraclePolicy)
    with pytest.raises(ValueError, match="true c1 and Ct.*make_env"):
        oracle.predict(np.zeros((1, 8)))
    low, high = oracle.gains_for(1.25e5, 5e-16), oracle.gains_for(2.25e6, 5e-9)
    assert not np.allclose(low, high)
    recs = run_episodes(oracle, [1, 2])
    assert all(np.isfinite(r["cost"]) for r in recs)


@pytest.mark.slow
@pytest.mark.parametrize("algo, backend", [("ppo", "sb3"), ("sac", "sb3"), ("recurrentppo", "sb3"), ("sac", "sbx"),
                                           ("ppo", "sbx")])
def test_each_algorithm_smoke_trains_and_resumes(tmp_path, algo, backend):
    if backend == "sbx":
        skip_without_sbx()
    policy = "MlpLstmPolicy" if algo == "recurrentppo" else "MlpPolicy"
    cfg = tmp_path / f"{algo}.yml"
    cfg.write_text(TINY.format(policy=policy, extra=EXTRA[algo]))
    kw = dict(config=str(cfg), log_dir=str(tmp_path / "runs"), eval_freq=128, n_eval_episodes=2,
              checkpoint_freq=128, progress=False, backend=backend, validation_episodes=QUICK_VALIDATION)
    card = train(algo, seed=3, save_dir=str(tmp_path / "agent"), **kw)
    assert card["n_timesteps"] >= 256 and card["seed"] == 3 and card["backend"] == backend
    for name in ("model.zip", "vecnormalize.npz", "card.json", "evaluations.npz"):  # the curve too
        assert (tmp_path / "agent" / name).exists()
    agent = load_controller(str(tmp_path / "agent"))
    assert agent.backend == backend
    # an sbx SAC is saved as SB3's SAC with its weights: it loads and runs without JAX
    fmt = "sb3" if (backend, algo) == ("sbx", "sac") else backend
    assert card["model_format"] == agent.model_format == fmt
    assert type(agent.model).__module__.split(".")[0] == {"sb3": "sb3_contrib" if algo == "recurrentppo"
                                                          else "stable_baselines3", "sbx": "sbx"}[fmt]
    recs = run_episodes(agent, [0, 1])
    assert all(np.isfinite(r["cost"]) for r in recs)
    if (backend, algo) == ("sbx", "sac"):
        from stable_baselines3 import SAC  # SB3's own loader: the plain recipe

        plain = SAC.load(tmp_path / "agent" / "model.zip", device="cpu")
        obs = np.random.default_rng(0).standard_normal((4, *plain.observation_space.shape)).astype(np.float32)
        np.testing.assert_allclose(plain.predict(obs, deterministic=True)[0],  # torch's float32 call-to-call rounding
                                   agent.model.predict(obs, deterministic=True)[0], rtol=0.0, atol=1e-5)
        if importlib.util.find_spec("onnxruntime") is not None:  # and it leaves Python as any SB3 agent
            from millvib_env.catalog.export import EXPORT_TOLERANCE, export_agent

            summary = export_agent(str(tmp_path / "agent"), tmp_path / "sac.onnx", check_steps=50, latency_calls=0)
            assert summary["max_abs_difference"] <= EXPORT_TOLERANCE
    if backend == "sbx" and algo == "ppo":
        return  # resuming is the same code for both backends (checkpoints, VecNormalize, the card); once per backend
    resumed = train(algo, seed=3, n_timesteps=512, resume=True, **kw)
    assert resumed["n_timesteps"] >= 512


def test_sac_trains_with_sbx_by_default_where_it_is_installed_and_everything_else_with_sb3():
    import importlib.util

    from millvib_env.catalog.agents import resolved_backend

    have_sbx = importlib.util.find_spec("sbx") is not None
    assert resolved_backend("sac") == ("sbx" if have_sbx else "sb3")
    assert resolved_backend("ppo") == resolved_backend("recurrentppo") == "sb3"
    assert resolved_backend("sac", "sb3") == "sb3" and resolved_backend("ppo", "sbx") == "sbx"


def test_jax_compilations_are_cached_beside_numbas_unless_the_user_chose(tmp_path, monkeypatch):
    from millvib_env import _jax_cache

    for var in ("JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS",
                "JAX_COMPILATION_CACHE_MAX_SIZE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delitem(sys.modules, "jax", raising=False)  # as in a process that has not imported JAX yet
    if importlib.util.find_spec("jax") is None:
        _jax_cache.configure()
        assert "JAX_COMPILATION_CACHE_DIR" not in os.environ  # no JAX, nothing to set
        return
    _jax_cache.configure()
    folder = Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    assert folder.parent == tmp_path / "millvib-env" and folder.is_dir()
    assert folder.name.startswith(f"jax-{importlib.metadata.version('jax')}-")
    assert os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] == "0"  # sbx's many small compilations too
    mine = str(tmp_path / "mine")
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", mine)
    _jax_cache.configure()
    assert os.environ["JAX_COMPILATION_CACHE_DIR"] == mine  # the user's own choice is kept


@pytest.mark.parametrize("backend", ["sb3", pytest.param("sbx", marks=pytest.mark.slow)])
def test_a_new_sac_starts_at_the_zero_action(backend):
    # the relative action's zero is the base controller: a new agent starts from it in either backend
    from millvib_env.catalog.agents import algo_class
    from millvib_env.envs.vec_env import make_vec_env
    from millvib_env.training.train import start_at_zero_action

    if backend == "sbx":
        skip_without_sbx()
    venv = make_vec_env("MillVib-GainSchedule-v0", 2, seed=0)
    model = algo_class("sac", backend)("MlpPolicy", venv, seed=0, device="cpu")
    obs = np.random.default_rng(0).standard_normal((16, *venv.observation_space.shape)).astype(np.float32)
    before = np.abs(model.predict(obs, deterministic=True)[0]).max()
    start_at_zero_action(model)
    after = np.abs(model.predict(obs, deterministic=True)[0]).max()
    assert after < 0.05 < before


def test_benchmark_is_deterministic_and_has_the_schema():
    a = public_json(run_benchmark(["pid-paper", "pid-robust"], episodes=4, progress=False))
    b = public_json(run_benchmark(["pid-paper", "pid-robust"], episodes=4, progress=False))
    assert a["controllers"] == b["controllers"]
    assert {"controllers", "seed", "episodes", "env_id"} <= set(a)
    for summary in a["controllers"].values():
        assert SCHEMA <= set(summary) and summary["episodes"] == 4


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
def test_benchmark_cli_writes_json_and_outputs(tmp_path):
    out = tmp_path / "bench.json"
    rc = cli_main(["benchmark", "--controllers", "pid-paper", "--episodes", "3", "--quiet", "--json", str(out),
                   "--out", str(tmp_path / "out")])
    assert rc == 0
    data = json.loads(out.read_text())
    assert SCHEMA <= set(data["controllers"]["pid-paper"])
    for name in ("episodes.csv", "benchmark.md", "severity_plane.png", "cost_bars.png"):
        assert (tmp_path / "out" / name).exists()
    from millvib_env.evaluation.benchmark import episode_costs

    back = episode_costs(tmp_path / "out")  # what a script reads back: every episode's cost, by its plant
    saved = json.loads((tmp_path / "out" / "benchmark.json").read_text())["controllers"]["pid-paper"]
    assert len(back["pid-paper"]) == 3 and all(k[0] == "" for k in back["pid-paper"])
    assert np.mean(list(back["pid-paper"].values())) == pytest.approx(saved["cost_mean"], rel=1e-9)


@pytest.mark.parametrize("name", list_agents())
def test_shipped_agents_load_and_run(name):
    agent = load_controller(name, seed=agent_seeds(name)[-1])
    assert {"algo", "env_id", "seed", "n_timesteps", "wall_time_s", "command"} <= set(agent.card)
    recs = run_episodes(agent, [20_000])  # one episode: the agent's observations, actions and card fit its env
    assert len(recs) == 1 and np.isfinite(recs[0]["cost"])


@pytest.mark.parametrize("name", list_agents())
def test_an_agents_deterministic_actions_are_sb3s_predict(name):
    """`AgentPolicy.predict` runs PPO's and SAC's policies without SB3's per-call wrapping (`deterministic_actor`)
    and without their learner (`acting_policy`: the policy alone, made from the file with no optimiser): the same
    torch operations on the same weights as the `predict` of the learner SB3's own `load` makes, batched and for one
    observation, on observations beyond the training range too. Equal within 1e-5 of the action's unit range:
    torch's float32 matrix products are not bit-reproducible from call to call (here the first call of a process
    differs from the next ones by up to 3e-6 in about half the processes, in SB3's predict alone)."""
    agent = load_controller(name, seed=agent_seeds(name)[0])
    assert agent._policy is None and agent._model is None and agent.policy is not None  # loaded at the first use
    if agent.recurrent:
        assert agent._act is None  # the LSTM's state goes through SB3's predict
        return
    assert agent._act is not None
    if agent.model_format == "sb3":  # acting loaded no learner and built no optimiser
        import torch

        optimizers = [m.optimizer for m in agent.policy.modules() if hasattr(m, "optimizer")]
        assert agent._model is None and optimizers
        assert not any(isinstance(o, torch.optim.Optimizer) for o in optimizers)
    shape = agent.policy.observation_space.shape
    obs = (np.random.default_rng(3).standard_normal((16, *shape)) * 3.0).astype(np.float32)
    normalized = agent.normalize(obs)
    close = dict(rtol=0.0, atol=1e-5)
    np.testing.assert_allclose(agent.predict(obs)[0], agent.model.predict(normalized, deterministic=True)[0], **close)
    one = agent.predict(obs[5])[0]
    assert one.shape == agent.model.action_space.shape
    np.testing.assert_allclose(one, agent.model.predict(normalized[5], deterministic=True)[0], **close)
    net = getattr(agent.policy, "action_net", None)
    if net is not None:  # PPO: means beyond the action space are clipped as SB3 clips them
        import torch

        with torch.no_grad():
            net.bias += 100.0
        assert np.all(agent.predict(obs)[0] == agent.model.action_space.high)


def test_default_benchmark_covers_the_shipped_agents():
    agents = list_agents()
    assert len(agents) >= 2, "the PPO and SAC gain schedulers are shipped under agents/"


def test_a_retired_agent_is_left_out_of_the_default_lineup_and_runs_when_named():
    """A card's ``retired`` (why: superseded) keeps the agent loadable by name, for earlier results, and out of a
    benchmark that names no controllers, and out of the 'answer' group; every other shipped agent of the task and
    version stays in."""
    from millvib_env.catalog.agents import agent_retired
    from millvib_env.evaluation.benchmark.lineup import answer_group, default_lineup

    task = get_task("rolling")
    retired = [a for a in list_agents(task, "v1") if agent_retired(a)]
    assert retired, "the earlier residual students are shipped retired"
    lineup = default_lineup("v1", task)
    assert not set(retired) & set(lineup) and not set(retired) & set(answer_group("v1", task))
    assert set(list_agents(task, "v1")) - set(retired) <= set(lineup)
    for name in retired:
        assert "superseded" in agent_retired(name)
        assert load_controller(name).name == name


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:rich is experimental")  # SB3's progress bar (tqdm.rich) says so at every start
def test_train_on_a_task_uses_its_seeds_and_records_it(tmp_path, capsys):
    cfg = tmp_path / "ppo.yml"
    cfg.write_text(TINY.format(policy="MlpPolicy", extra=EXTRA["ppo"]))
    card = train("ppo", task="rolling", seed=1, config=str(cfg), log_dir=str(tmp_path / "runs"), eval_freq=128,
                 n_eval_episodes=2, checkpoint_freq=128, progress=True, save_dir=str(tmp_path / "agent"),
                 validation_episodes=QUICK_VALIDATION)
    said = capsys.readouterr().err  # where it writes, as it starts; what the silent seconds at the end are
    assert f"logs and checkpoints in {tmp_path / 'runs'}" in said and f"the agent to {tmp_path / 'agent'}" in said
    assert "on rolling's validation plants 115000-115003" in said
    assert card["task"] == "rolling" and card["env_kwargs"]["config"] == "rolling"
    assert card["validation"]["seeds"] == "115000-115003" and card["validation"]["episodes"] == QUICK_VALIDATION
    with pytest.raises(ValueError, match="trained on task 'rolling'"):
        run_benchmark([str(tmp_path / "agent")], task="startup", episodes=1, progress=False)
    result = run_benchmark([str(tmp_path / "agent"), "pid-robust"], task="rolling", episodes=2, progress=False)
    assert result["task"] == "rolling" and result["seed"] == 0
    assert all(p in get_task("rolling").seeds["heldout"] for p in result["plants"])


@pytest.mark.slow
def test_seeds_train_in_local_processes_each_with_its_card(tmp_path):
    from millvib_env.training.train import train_seeds

    cfg = tmp_path / "ppo.yml"
    cfg.write_text(TINY.format(policy="MlpPolicy", extra=EXTRA["ppo"]))
    cards = train_seeds([4, 5], jobs=2, save_dir=str(tmp_path / "agent"), algo="ppo", config=str(cfg),
                        log_dir=str(tmp_path / "runs"), eval_freq=128, n_eval_episodes=2, checkpoint_freq=128,
                        validation_episodes=QUICK_VALIDATION)
    assert [c["seed"] for c in cards] == [4, 5]
    for s in (4, 5):
        assert (tmp_path / "agent" / f"seed-{s}" / "card.json").exists()
        assert (tmp_path / "runs" / f"ppo_MillVib-GainSchedule-v1_s{s}" / "card.json").exists()
    assert agent_seeds(str(tmp_path / "agent")) == [4, 5]
    two = load_controller(str(tmp_path / "agent"), seed=5)
    assert two.seed == 5 and two.name == "agent"
    with pytest.raises(ValueError, match="no training seed 6"):
        load_controller(str(tmp_path / "agent"), seed=6)
    with pytest.raises(ValueError, match="training seed 60"):
        train_seeds([60], algo="ppo", config=str(cfg))


def test_sweep_cli_writes_its_folder(tmp_path):
    out = tmp_path / "sweep"
    assert cli_main(["sweep", "--controllers", "pid-paper", "pid-robust", "--plants", "4", "--params", "c1", "Ct",
                     "beta_e", "--out", str(out), "--quiet"]) == 0
    for name in ("plants.csv", "summary.json", "maps.png"):
        assert (out / name).exists()
    data = json.loads((out / "summary.json").read_text())
    assert data["plants"] == 4 and set(data["controllers"]) == {"pid-paper", "pid-robust"}
    assert data["seed"] == 60_000  # 40000 into startup's held-out range
    # --no-figures: the data alone; the folder, its own previous result, is replaced as a whole
    assert cli_main(["sweep", "--controllers", "pid-paper", "--plants", "1", "--out", str(out), "--quiet",
                     "--no-figures"]) == 0
    assert (out / "plants.csv").exists() and not (out / "maps.png").exists()


@pytest.mark.slow
@pytest.mark.parametrize("form", ["true", "false", "\"dict(norm_obs=True, norm_reward=False)\"", "{norm_obs: true}"])
def test_every_normalize_form_train_accepts_saves_an_agent_that_loads_and_benchmarks(tmp_path, form):
    cfg = tmp_path / "ppo.yml"
    cfg.write_text(TINY.format(policy="MlpPolicy", extra=EXTRA["ppo"]).replace(
        'normalize: "dict(norm_obs=True, norm_reward=True)"', f"normalize: {form}"))
    card = train("ppo", task="startup", seed=2, config=str(cfg), log_dir=str(tmp_path / "runs"), eval_freq=128,
                 n_eval_episodes=2, checkpoint_freq=128, progress=False, save_dir=str(tmp_path / "agent"),
                 validation_episodes=2)
    agent = load_controller(str(tmp_path / "agent"))
    assert (agent._stats_path is None) == (form == "false") and card["normalize"] != "True"
    result = run_benchmark([str(tmp_path / "agent")], task="startup", episodes=1, progress=False)
    assert all(np.isfinite(row["cost_mean"]) for row in result["controllers"].values())


def test_the_zoo_forms_of_normalize_are_read_as_data_and_a_bad_one_is_refused_in_one_line():
    from millvib_env.catalog.normalization import normalize_kwargs, normalizes_obs

    both = {"norm_obs": True, "norm_reward": True}
    for form, want in ((True, both), ("True", both), (False, None), ("None", None), (None, None),
                       ("dict(norm_obs=True, norm_reward=False)", {"norm_obs": True, "norm_reward": False}),
                       ({"clip_obs": 5.0}, {**both, "clip_obs": 5.0}), ("{'norm_obs': False}",
                                                                       {"norm_obs": False, "norm_reward": True})):
        assert normalize_kwargs(form) == want, form
    assert not normalizes_obs("{'norm_obs': False}") and normalizes_obs("{'norm_obs': True}")
    assert not normalizes_obs("{}")  # an early card's text for none
    for bad in ("yes", "dict(norm_obs=os.system('x'))", {"foo": 1}, {"norm_obs": "x"}, {"clip_obs": -1.0}):
        with pytest.raises(ValueError, match="normalize = .* is invalid"):
            normalize_kwargs(bad)


def test_a_task_configs_own_id_and_a_shipped_file_by_name_are_found_from_any_directory(tmp_path, monkeypatch):
    from millvib_env.training.hyperparams import load_hyperparams, shipped_hyperparams

    monkeypatch.chdir(tmp_path)
    assert shipped_hyperparams("pf/ppo") == shipped_hyperparams("configs/agents/pf/ppo.yml")
    assert shipped_hyperparams("pf/ppo.yml").is_file()
    with pytest.raises(ValueError, match=r"not found; the shipped ones, by name: .*'pf/ppo'"):
        shipped_hyperparams("pf/nope")
    for algo in ("ppo", "sac", "recurrentppo"):
        generic = load_hyperparams(algo, "MillVib-GainSchedule-v1")
        assert load_hyperparams(algo, "MillVib-GainSchedule-Rolling-v1") == generic


@pytest.mark.slow
def test_init_from_starts_rl_at_a_distilled_student_and_refuses_another_network(tmp_path):
    """`train --init-from`: the run's environment is the student's (its card's env_kwargs, the classical
    feedforward included), its starting policy the student's network and statistics; the card says so."""
    import torch

    student = load_controller("dagger-on-pid-pf-preview-varied")
    cfg = tmp_path / "ppo.yml"
    body = ("MillVib-Valve-v1:\n  n_envs: 2\n  n_timesteps: 128\n  policy: MlpPolicy\n  normalize: true\n"
            "  n_steps: 64\n  batch_size: 64\n  n_epochs: 1\n  learning_rate: 0.0\n"
            "  policy_kwargs: \"dict(log_std_init=-3.0, net_arch=dict(pi=[256, 256], vf=[64, 64]))\"\n")
    cfg.write_text(body)
    card = train("ppo", "MillVib-Valve-v1", task="varied", seed=0, config=str(cfg), log_dir=str(tmp_path / "runs"),
                 eval_freq=10_000, n_eval_episodes=1, checkpoint_freq=10_000, progress=False,
                 save_dir=str(tmp_path / "agent"), validation_episodes=1, init_from="dagger-on-pid-pf-preview-varied")
    assert card["init_from"]["name"] == "dagger-on-pid-pf-preview-varied"
    assert card["env_kwargs"] == student.env_kwargs and "residual_feedforward" in card["env_kwargs"]["actions"]
    tuned = load_controller(str(tmp_path / "agent"))
    for (k, a), b in zip(student.model.policy.state_dict().items(), tuned.model.policy.state_dict().values()):
        if "value_net" not in k and "mlp_extractor.value_net" not in k:  # learning rate 0: the actor as it was
            assert torch.equal(a, b), k
    cfg.write_text(body.replace("pi=[256, 256]", "pi=[64]"))
    with pytest.raises(ValueError, match="its network differs"):
        train("ppo", "MillVib-Valve-v1", task="varied", seed=0, config=str(cfg), log_dir=str(tmp_path / "runs2"),
              progress=False, init_from="dagger-on-pid-pf-preview-varied")


def test_episode_cost_reward_weighs_a_period_by_what_it_adds_to_the_episodes_cost():
    """`EpisodeCostReward`: on a steady signal the config's reward; a loud period after quiet ones costs more than
    its own RMS (the cost's slope at the episode's level), a quiet one after loud ones less; the config's other
    terms (the penalty) are kept; each environment's sums restart after the period that ends its episode."""
    from millvib_env.envs.reward import EpisodeCostReward, RewardTerms

    def terms(v_mm_s, e_um, left, penalty=(0.0, 0.0)):
        v, e = np.array(v_mm_s) * 1e-3, np.array(e_um) * 1e-6
        config = -(v / 4.5e-3 + e / 10e-6) - np.array(penalty)  # the config's reward (weights 1)
        return config, RewardTerms(v, e, np.zeros(2), np.zeros(2), np.array(penalty) > 0, np.array(left), config)

    r = EpisodeCostReward()
    config, t = terms([4.5, 9.0], [10.0, 5.0], [5, 5])
    np.testing.assert_allclose(r(t), config, rtol=1e-12)  # the first period: its own level
    config, t = terms([4.5, 0.0], [10.0, 0.0], [4, 4])
    got = r(t)
    assert got[0] == pytest.approx(config[0], rel=1e-12)  # steady
    assert got[1] == 0.0  # silence adds nothing either way
    config, t = terms([9.0, 3.0], [10.0, 2.0], [3, 3])
    got = r(t)
    assert got[0] < config[0]  # louder than the episode so far: more than its own RMS
    assert got[1] > config[1]  # quieter than the episode so far: less
    config, t = terms([4.5, 4.5], [10.0, 10.0], [0, 2], penalty=(1000.0, 0.0))
    assert r(t)[0] < -1000.0  # the penalty kept
    assert r.count is not None and r.count[0] == 0 and r.count[1] == 4  # env 0's episode ended: its sums restart


def test_finetune_starts_at_the_student_scores_on_validation_and_writes_a_trained_agent(tmp_path):
    """`millvib finetune`: the critic alone first (the actor as the student's until the warm-up ends), the actor
    scored on validation plants after it, the best of those written as an agent folder that loads by path, with a
    card that names its student; bad numbers are refused in one line."""
    import torch

    from millvib_env.catalog.agents import read_card
    from millvib_env.training.finetune import ACTOR_KEYS, finetune

    folder = "agents/dagger-on-pid-pf-preview-rolling/seed-0"
    student = load_controller(folder)
    card = finetune(folder, save_dir=tmp_path / "ft", steps=384, warmup=256, eval_every=128, n_envs=2, n_steps=64,
                    validation_episodes=1, reward="episode-cost", progress=False)
    assert [r["steps"] for r in card["curve"]] == [384]  # after the warm-up only
    assert card["selected"]["steps"] == 384 and card["init_from"]["name"] == student.name
    assert card["on"] == "pid-pf-preview" and card["env_kwargs"] == read_card(f"{folder}/card.json")["env_kwargs"]
    assert card["hyperparameters"]["reward"] == "episode-cost" and card["task"] == "rolling"
    tuned = load_controller(str(tmp_path / "ft"))
    np.testing.assert_array_equal(tuned.obs_stats.mean, student.obs_stats.mean)  # the student's statistics
    moved = [k for k, v in tuned.model.policy.state_dict().items()
             if k.startswith(ACTOR_KEYS) and not torch.equal(v, student.model.policy.state_dict()[k])]
    assert moved  # 128 steps of the actor's own
    for bad, match in [(dict(warmup=384), "warmup"), (dict(actor_lr=-1.0), "actor_lr"),
                       (dict(reward="cost"), "reward")]:
        with pytest.raises(ValueError, match=match):
            finetune(folder, save_dir=tmp_path / "bad", **{"steps": 384, "warmup": 0, **bad})
    with pytest.raises(ValueError, match="student"):
        finetune(tmp_path, save_dir=tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_the_evolution_strategies_batch_gives_each_candidate_its_own_output_layer():
    """`scripts/es_output_layer.py` runs every candidate of a generation in one batch of environments: row r of the
    batch must act with candidate r // plants's layer, as a torch Linear with that candidate's weights does."""
    import runpy

    import torch

    script = runpy.run_path(str(Path(__file__).parents[1] / "scripts" / "es_output_layer.py"))
    rng = np.random.default_rng(3)
    thetas, plants = rng.standard_normal((4, 9)), 3
    latent = torch.as_tensor(rng.standard_normal((4 * plants, 8)), dtype=torch.float32)
    out = script["RowLinear"](thetas, plants, 8)(latent)
    assert out.shape == (4 * plants, 1)
    for r in range(4 * plants):
        one = torch.nn.Linear(8, 1)
        with torch.no_grad():
            one.weight.copy_(torch.as_tensor(thetas[r // plants, :8][None], dtype=torch.float32))
            one.bias.copy_(torch.as_tensor(thetas[r // plants, 8:], dtype=torch.float32))
        assert torch.allclose(out[r], one(latent[r]), rtol=1e-5, atol=1e-5)  # float32 sums in another order


def test_an_interrupted_sweep_keeps_its_finished_jobs_and_resume_writes_the_same_files(monkeypatch, tmp_path, capsys):
    """A Ctrl-C in `millvib sweep` keeps the finished jobs' episodes in the folder's journal and says so in its one
    line; the same command refuses to start over them, another sweep's options cannot resume them, and `--resume`
    runs only the jobs left (after a line the interruption cut short) to the files an uninterrupted run writes."""
    from millvib_env.evaluation import sweep

    real, calls, stop = sweep.episode_records, [], {"at": 3}

    def records(**job):
        calls.append(job["seeds"])
        if len(calls) == stop["at"]:
            raise KeyboardInterrupt
        return real(**job)

    monkeypatch.setattr(sweep, "episode_records", records)
    monkeypatch.setattr(sweep, "CHUNK", 1)  # a job a plant
    out, journal = tmp_path / "sweep", tmp_path / "sweep.partial"
    command = ["sweep", "--controllers", "pid-paper", "--plants", "4", "--out", str(out), "--quiet", "--no-figures"]
    assert cli_main(command) == 130
    said = capsys.readouterr().err.strip().splitlines()
    assert said == [f"millvib sweep: interrupted; 2 of 4 jobs are kept in {journal}: the same command with --resume "
                    "goes on from them"]
    assert not out.exists() and len(journal.read_text().splitlines()) == 3
    assert cli_main(command) == 2
    assert "add --resume to go on from them" in capsys.readouterr().err
    assert cli_main([*command[:4], "3", *command[5:], "--resume"]) == 2
    assert "journal of another sweep (plants 4 there, 3 here)" in capsys.readouterr().err

    with open(journal, "a") as f:
        f.write('{"job": 2, "rec')  # the line a job was writing when the machine went
    stop["at"], calls[:] = 0, []
    assert cli_main([*command, "--resume"]) == 0
    assert len(calls) == 2 and not journal.exists()  # jobs 2 and 3
    whole = tmp_path / "whole"
    assert cli_main(["sweep", "--controllers", "pid-paper", "--plants", "4", "--out", str(whole), "--quiet",
                     "--no-figures"]) == 0
    for name in ("plants.csv", "summary.json"):
        assert (out / name).read_bytes() == (whole / name).read_bytes()
