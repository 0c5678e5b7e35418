"""Pressure feedback, force feedforward and the relative gain action (the classical controllers to beat)."""
import numpy as np
import pytest

import millvib_env
from millvib_env.catalog.factory import load_controller
from millvib_env.catalog.registry import REFERENCE
from millvib_env.catalog.named import named_gains
from millvib_env.envs.actions import GainMap
from millvib_env.envs.config import load_env_config
from millvib_env.tasks import get_task
from millvib_env.evaluation.evaluate import run_episodes

BASE = [1.15e6, 8.0e8, 300.0, 1.5e-4]


def _rel_config(decades=(1.0, 1.0, 0.0, 1.0), base=BASE, **kw):
    return load_env_config("rolling", actions={"pressure_feedback": True,
                                               "relative": {"base": list(base), "decades": list(decades)}}, **kw)


def test_the_relative_map_gives_exactly_the_base_gains_at_zero_and_clips_offsets():
    gm = GainMap.from_config(_rel_config())
    assert gm.relative and gm.dim == 4
    assert np.array_equal(gm.gains(np.zeros(4)), np.array(BASE))
    g = gm.gains(np.array([5.0, -7.0, 1.0, 1.0]))  # outside the box: clipped to +-1 decade
    assert np.allclose(g, [BASE[0] * 10, BASE[1] / 10, BASE[2], BASE[3] * 10])
    assert np.allclose(gm.action(gm.gains(np.array([0.3, -0.2, 0.0, 0.5]))), [0.3, -0.2, 0.0, 0.5])


def test_the_relative_action_at_zero_runs_the_same_trajectory_as_the_fixed_policy_with_its_gains():
    from millvib_env.control.policies import FixedGainPolicy

    fixed = FixedGainPolicy("pf", BASE)
    seeds = [120001, 120002, 120003]
    a = run_episodes(fixed, seeds, task="rolling")
    venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 3, seed=0, config="rolling",
                                    actions={"pressure_feedback": True, "relative": {"base": BASE}},
                                    monitor=False)
    venv._seeds = seeds
    venv.reset()
    done = np.zeros(3, bool)
    infos = None
    while not done.all():
        _, _, d, infos = venv.step(np.zeros((3, 4)))
        done |= d
    for rec, info in zip(a, infos):
        assert rec["severity_mm_s"] == info["severity"] and rec["tracking_rms_um"] == info["tracking_rms_um"]


def test_a_named_base_is_resolved_from_the_tasks_control_config_before_the_env():
    import gymnasium as gym

    from millvib_env.catalog.named import resolve_named_gains

    env = gym.make("MillVib-GainSchedule-v0", config="rolling",  # as the zoo passes a file's env_kwargs
                   actions={"pressure_feedback": True, "relative": {"base": "pid-pf-robust"}})
    assert list(env.unwrapped.core.settings.gain_map.base) == named_gains("pid-pf-robust", get_task("rolling"), "v0")
    kw = resolve_named_gains({"actions": {"pressure_feedback": True, "relative": {"base": "pid-pf-robust"},
                                          "residual_gains": "pid-pf-ff"}}, "rolling")
    assert kw["actions"]["relative"]["base"] == named_gains("pid-pf-robust", get_task("rolling"))  # numbers
    assert len(kw["actions"]["residual_gains"]) == 5
    assert resolve_named_gains({"config": "change", "actions": {"residual_gains": "pid-pf-ff"}}, version="v1")[
        "actions"]["residual_gains"] == named_gains("pid-pf-ff", get_task("change"), "v1")  # the task its config names
    with pytest.raises(ValueError, match="gains 'bogus' unknown"):
        resolve_named_gains({"actions": {"residual_gains": "bogus"}}, "rolling")
    for actions in ({"residual_gains": "pid-pf-ff"}, {"relative": {"base": "pid-pf-robust"}}):
        with pytest.raises(ValueError, match="takes gains as numbers"):  # the env layer itself: numbers only
            load_env_config("rolling", actions=actions)


def test_a_base_of_the_wrong_length_is_an_error():
    with pytest.raises(ValueError, match="needs 4 gains"):
        GainMap.from_config(_rel_config(base=BASE[:3], decades=(1, 1, 0)))


def test_force_feedforward_is_off_by_default_and_the_force_observation_is_an_option():
    venv = millvib_env.make_vec_env("MillVib-Valve-v0", 2, seed=0, config="rolling", residual=True,
                                    observation={"force": True})
    assert venv.core.obs_names[-1] == "load_force"
    obs = venv.reset()
    for _ in range(50):
        obs, *_ = venv.step(np.zeros((2, 1)))
    assert np.all(np.isfinite(obs)) and np.any(obs[:, -1] != 0)  # eccentricity moves the force


@pytest.mark.parametrize("task", ["rolling", "change"])
def test_pid_pf_robust_is_the_reference_and_beats_pid_robust_on_the_tuning_plants(task):
    from millvib_env.catalog.factory import control_entry

    assert REFERENCE == "pid-pf-robust"
    t = get_task(task)
    assert control_entry(t, "pid-pf-robust")["tuning_cost"] < control_entry(t, "pid-robust")["tuning_cost"]
    assert len(named_gains("pid-pf-robust", t)) == 4 and len(named_gains("pid-pf-ff", t)) == 5


def test_pid_pf_robust_is_stable_on_the_linearisation_of_every_oracle_grid_plant():
    from millvib_env.analysis.linear import spectral_abscissa
    from millvib_env.catalog.factory import control_entry
    from millvib_env.params import PIDGains

    for task in ("startup", "rolling", "change"):
        gains = PIDGains(*named_gains("pid-pf-robust", get_task(task)))
        entry = control_entry(get_task(task), "pid-oracle")
        base = load_env_config(task).base_params
        for c1 in entry["c1_grid"]:
            for ct in entry["ct_grid"]:
                for friction in ("stick", "sliding"):
                    sa = spectral_abscissa(base.replace(c1=c1, Ct=ct), gains, friction=friction, integral="settled")
                    assert sa < 0, (task, c1, ct, friction, sa)


PLAIN_LOOP_NAMES = ["pid-paper", "pid-robust", "pid-oracle", "pid-adaptive", "lqr-oracle", "pid-pf-robust",
                    "pid-pf-ff", "pid-pf-oracle"]


def _plain_loop_cost(ctrl, seed: int) -> float:
    from millvib_env.evaluation.evaluate import episode_cost

    env = ctrl.make_env()
    obs, info = env.reset(seed=seed)
    done = False
    while not done:
        action, _ = ctrl.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    return episode_cost(info["severity"], info["tracking_rms_um"])


@pytest.mark.slow  # every controller for an episode: the full suite runs it, the quick subset does not
@pytest.mark.parametrize("task", ["startup", "rolling"])
def test_every_controller_gives_the_benchmark_cost_in_a_plain_gymnasium_loop(task):
    from millvib_env.catalog.agents import list_agents
    from millvib_env.tasks import get_task

    seed = get_task(task).seeds["heldout"].start + 7
    agents = list_agents(task)
    # every baseline on startup; on rolling its agents and the reference (a baseline's loop is the same code on
    # either task: the rolling case is there for the agents trained on its disturbances)
    baselines = PLAIN_LOOP_NAMES if task == "startup" else ["pid-pf-robust"]
    for name in baselines + agents:
        ctrl = load_controller(name, task)
        expected = run_episodes(load_controller(name, task), [seed], task=task)[0]["cost"]
        assert _plain_loop_cost(ctrl, seed) == pytest.approx(expected, rel=1e-9), name
