"""A trained agent leaves Python as an ONNX graph that acts as the agent does."""
import json

import numpy as np
import pytest

pytest.importorskip("onnxruntime")

from millvib_env.catalog.export import EXPORT_TOLERANCE, export_agent  # noqa: E402
from tests._skips import skip_without_sbx  # noqa: E402


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The shipped student of the startup task, seed 0, exported once for the module: (its file, the summary)."""
    out = tmp_path_factory.mktemp("export") / "policy.onnx"
    return out, export_agent("dagger-residual-preview", out, seed=0, check_steps=50, latency_calls=0)


def test_the_exported_graph_acts_as_the_agent_on_observations_it_was_not_checked_on(exported, tmp_path):
    import onnx
    import onnxruntime as ort

    from millvib_env.catalog.factory import load_controller
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.evaluation.evaluate import env_kwargs_for

    out, summary = exported
    assert summary["max_abs_difference"] <= EXPORT_TOLERANCE and "latency_us" not in summary
    agent = load_controller("dagger-residual-preview", seed=0)
    venv = EpisodeBatch(agent.env_id, 3, **env_kwargs_for(agent, agent.task, None))
    obs, seen = venv.reset([20000, 20001, 20002]), []
    for _ in range(60):  # other plants, other states, a batch of three
        seen.append(obs.copy())
        obs = venv.step(agent.predict(obs)[0])[0]
    seen = np.concatenate(seen).astype(np.float32)
    session = ort.InferenceSession(out.read_bytes(), providers=["CPUExecutionProvider"])
    got = session.run(["action"], {"observation": seen})[0]
    np.testing.assert_allclose(got, agent.predict(seen)[0], atol=EXPORT_TOLERANCE, rtol=0)
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert json.loads(meta["millvib.observation"]) == list(venv.core.obs_names)
    assert meta["millvib.task"] == "startup" and "100.0" in meta["millvib.action"]
    # a SAC agent's squashed mean and a gain schedule, checked the same way before it is written
    assert export_agent("sac-gain-pf", tmp_path / "sac.onnx", check_steps=20, latency_calls=0)[
        "max_abs_difference"] <= EXPORT_TOLERANCE


def test_a_baseline_or_a_bad_path_is_refused_in_one_line(tmp_path, capsys):
    from millvib_env.cli import main

    with pytest.raises(ValueError, match="baseline"):
        export_agent("pid-paper", tmp_path / "x.onnx")
    assert main(["export", "dagger-residual-preview", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]
    assert not list(tmp_path.iterdir())


@pytest.mark.slow  # imports JAX: seconds
def test_an_sbx_sac_is_sb3s_sac_weight_for_weight():
    """sbx's SAC copied into SB3's (`catalog.sbx_to_sb3`): the deterministic actions and both critics' values agree
    within float32 rounding (JAX and torch sum in their own order), on observations beyond the usual range."""
    skip_without_sbx()
    import torch

    from millvib_env.catalog.agents import algo_class
    from millvib_env.catalog.sbx_to_sb3 import sb3_sac_from_sbx
    from millvib_env.envs.vec_env import make_vec_env

    venv = make_vec_env("MillVib-GainSchedule-v1", 2, seed=0)
    model = algo_class("sac", "sbx")("MlpPolicy", venv, seed=0, policy_kwargs={"net_arch": [32, 16]})
    sb3 = sb3_sac_from_sbx(model)
    rng = np.random.default_rng(0)
    obs = (rng.standard_normal((64, *venv.observation_space.shape)) * 3.0).astype(np.float32)
    act = rng.uniform(-1.0, 1.0, (64, *venv.action_space.shape)).astype(np.float32)
    np.testing.assert_allclose(sb3.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0],
                               rtol=0.0, atol=1e-5)
    with torch.no_grad():
        q_sb3 = torch.stack(sb3.critic(torch.as_tensor(obs), torch.as_tensor(act))).numpy()
    q_sbx = np.asarray(model.policy.qf.apply(model.policy.qf_state.params, obs, act))
    np.testing.assert_allclose(q_sb3, q_sbx, rtol=1e-4, atol=1e-5)
    with pytest.raises(ValueError, match="an sbx SAC"):
        sb3_sac_from_sbx(sb3)


@pytest.mark.slow  # a fresh process: seconds
def test_the_benchmark_runs_an_exported_graph_without_torch_and_gives_the_agents_row(exported, tmp_path):
    """`millvib benchmark --controllers FILE.onnx` in a fresh process imports neither torch nor SB3, and its row is
    the SB3 agent's on the same plants within the float32 rounding of the actions (<= 1e-5 each) carried through the
    closed loop: relative 1e-3 (3e-5 measured on these plants)."""
    import subprocess
    import sys

    from millvib_env.evaluation.benchmark import run_benchmark

    out, _ = exported
    kw = ["--task", "startup", "--episodes", "3", "--no-scenarios", "--quiet"]
    code = ("import sys; from millvib_env.cli import main; rc = main(sys.argv[1:]); "
            "print(rc, 'torch' in sys.modules, 'stable_baselines3' in sys.modules, 'jax' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code, "benchmark", "--controllers", str(out), *kw,
                          "--json", str(tmp_path / "onnx.json")], capture_output=True, text=True, timeout=300)
    assert run.stdout.strip().splitlines()[-1] == "0 False False False", run.stdout + run.stderr
    got = json.loads((tmp_path / "onnx.json").read_text())["controllers"][str(out)]
    want = run_benchmark(["dagger-residual-preview"], task="startup", episodes=3, scenarios=False,
                         progress=False)["controllers"]["dagger-residual-preview"]
    assert got["n_seeds"] == want["n_seeds"] == 1 and got["episodes"] == want["episodes"] == 3
    for key in ("cost_mean", "cost_cvar20", "cost_worst", "severity_mean", "tracking_rms_um_mean"):
        assert got[key] == pytest.approx(want[key], rel=1e-3), key
    assert got["paired"]["pid-pf-robust"]["p_improvement"] == want["paired"]["pid-pf-robust"]["p_improvement"]


def test_an_exported_graph_is_a_controller_and_a_damaged_one_is_one_line(exported, tmp_path):
    """`load_controller` takes the graph as its agent's seed on its agent's task; a graph of another task or seed,
    a file that is no graph, and a graph without the export's metadata or with an environment it cannot have are
    refused in one line each."""
    import onnx

    from millvib_env.catalog.factory import load_controller
    from millvib_env.catalog.onnx_policy import OnnxPolicy
    from millvib_env.evaluation.evaluate import run_episodes

    out, _ = exported
    policy = load_controller(str(out), "startup")
    assert isinstance(policy, OnnxPolicy) and (policy.seed, policy.task.name, policy.agent) == \
        (0, "startup", "dagger-residual-preview")
    agent = load_controller("dagger-residual-preview", seed=0)
    assert run_episodes(policy, [20000])[0]["cost"] == pytest.approx(run_episodes(agent, [20000])[0]["cost"], rel=1e-3)
    one = np.zeros(len(agent.model.observation_space.low), dtype=np.float32)
    assert policy.predict(one)[0].shape == agent.predict(one)[0].shape  # one observation, or a batch
    with pytest.raises(ValueError, match="trained on task 'startup', not 'rolling'"):
        load_controller(str(out), "rolling")
    with pytest.raises(ValueError, match="holds training seed 0 .* not seed 3"):
        load_controller(str(out), seed=3)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a graph")
    with pytest.raises(ValueError, match="not an ONNX graph onnxruntime can run"):
        load_controller(str(junk))
    with pytest.raises(ValueError, match="cannot be read"):
        load_controller(str(tmp_path / "absent.onnx"))
    model = onnx.load(str(out))
    exported_props = {p.key: p.value for p in model.metadata_props}
    for key, value, match in [("millvib.task", None, "metadata .*millvib.task.* missing"),
                              ("millvib.seed", "x", "millvib.seed = 'x' is invalid"),
                              ("millvib.env_id", "CartPole-v1", "millvib.env_id = 'CartPole-v1' is invalid"),
                              ("millvib.env_kwargs", '{"seed_offset": 3}', "would change the episode"),
                              ("millvib.observation", '["x"]', "export the agent again")]:
        props = dict(exported_props)
        props.pop(key) if value is None else props.update({key: value})
        del model.metadata_props[:]
        onnx.helper.set_model_props(model, props)
        bad = tmp_path / f"{key}.onnx"
        bad.write_bytes(model.SerializeToString())
        with pytest.raises(ValueError, match=match) as err:
            load_controller(str(bad))
        assert "\n" not in str(err.value)
