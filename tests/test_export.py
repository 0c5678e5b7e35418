"""A trained agent leaves Python as an ONNX graph that acts as the agent does."""
import json

import numpy as np
import pytest

pytest.importorskip("onnxruntime")

from millvib_env.control.export import EXPORT_TOLERANCE, export_agent  # noqa: E402


def test_the_exported_graph_acts_as_the_agent_on_observations_it_was_not_checked_on(tmp_path):
    import onnx
    import onnxruntime as ort

    from millvib_env.control.factory import load_controller
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.training.evaluate import env_kwargs_for

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
