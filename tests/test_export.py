"""A trained agent leaves Python as an ONNX graph that acts as the agent does."""
import json

import numpy as np
import pytest

pytest.importorskip("onnxruntime")

from millvib_env.control.export import EXPORT_TOLERANCE, export_agent  # noqa: E402
from tests._skips import skip_without_sbx  # noqa: E402


def test_the_exported_graph_acts_as_the_agent_on_observations_it_was_not_checked_on(tmp_path):
    import onnx
    import onnxruntime as ort

    from millvib_env.control.factory import load_controller
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.evaluation.evaluate import env_kwargs_for

    out = tmp_path / "policy.onnx"
    summary = export_agent("dagger-residual-preview", out, seed=0, check_steps=50, latency_calls=0)
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


def test_an_sbx_sac_is_sb3s_sac_weight_for_weight():
    """sbx's SAC copied into SB3's (`control.sbx_to_sb3`): the deterministic actions and both critics' values agree
    within float32 rounding (JAX and torch sum in their own order), on observations beyond the usual range."""
    skip_without_sbx()
    import torch

    from millvib_env.control.agents import algo_class
    from millvib_env.control.sbx_to_sb3 import sb3_sac_from_sbx
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
