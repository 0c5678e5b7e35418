"""The Gymnasium environments: API conformance, seeding, plant draws, batching, robustness."""
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from scipy import stats
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.vec_env import DummyVecEnv

import millvib_env
from millvib_env.envs.scenarios import list_scenarios
from millvib_env.envs.config import load_env_config
from millvib_env.envs.specs import ENV_SPECS

#: the valve envs' episodes cut to 0.2 s (200 steps of 1 ms on v0, 400 of 0.5 ms on v1), so that a case steps
#: through two whole episodes and an auto-reset in a few hundred steps
ENV_CASES = [("MillVib-GainSchedule-v0", {}), ("MillVib-Valve-v0", {"episode_s": 0.2}),
             ("MillVib-Valve-v0", {"residual": True, "episode_s": 0.2}),
             ("MillVib-GainSchedule-v1", {"config": "rolling"}),
             ("MillVib-Valve-v1", {"residual": True, "episode_s": 0.2})]


@pytest.mark.parametrize("env_id, kwargs", ENV_CASES)
def test_gymnasium_and_sb3_checkers_pass(env_id, kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any checker warning fails the test ...
        # ... but Gymnasium's own note that a v0 has a newer version, which is its version discipline at work
        warnings.filterwarnings("ignore", message=".*is out of date.*", category=DeprecationWarning)
        gym_check_env(gym.make(env_id, **kwargs).unwrapped, skip_render_check=True)
    sb3_check_env(gym.make(env_id, **kwargs), warn=True)


def test_a_v0_id_says_that_v1_exists_and_v1_does_not():
    with pytest.warns(DeprecationWarning, match="out of date"):
        gym.make("MillVib-GainSchedule-v0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym.make("MillVib-GainSchedule-v1")


def _zero_action_episode(env):
    """One episode of zero actions from plant seed 0: (its steps, the last terminated and truncated)."""
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape)
    steps, term, trunc = 0, False, False
    while not (term or trunc):
        _, _, term, trunc, _ = env.step(action)
        steps += 1
    return steps, term, trunc


@pytest.mark.parametrize("env_id", ["MillVib-GainSchedule-v0", "MillVib-Valve-v0"])
@pytest.mark.parametrize("config, seconds", [("startup", 0.5), ("rolling", 1.0)])
def test_episodes_truncate_at_the_configs_length(env_id, config, seconds):
    env = gym.make(env_id, config=config)
    assert gym.spec(env_id).max_episode_steps is None  # a generic id takes any config: the env ends its episodes
    period = 0.01 if "Gain" in env_id else 0.001
    steps, term, trunc = _zero_action_episode(env)
    assert trunc and not term and steps == round(seconds / period)


@pytest.mark.parametrize("env_id", [i for i, s in ENV_SPECS.items() if s.config is not None])
def test_a_per_task_id_carries_its_episode_length(env_id):
    spec = ENV_SPECS[env_id]
    config = load_env_config(spec.config, version=spec.version)
    period = config.decision_dt_s if spec.mode == "gain" else config.control_dt_s
    assert gym.spec(env_id).max_episode_steps == round(config.episode_s / period)


@pytest.mark.parametrize("env_id", ["MillVib-Valve-Rolling-v1", "MillVib-GainSchedule-Startup-v1"])
def test_a_per_task_ids_timelimit_is_where_the_env_truncates(env_id):
    env = gym.make(env_id)
    assert isinstance(env, gym.wrappers.TimeLimit)
    steps, term, trunc = _zero_action_episode(env)
    assert trunc and not term and steps == gym.spec(env_id).max_episode_steps
    assert env.unwrapped.core.k[0] == steps  # the environment's own truncation, not one the wrapper imposed


@pytest.mark.parametrize("make", [lambda **kw: gym.make("MillVib-Valve-Rolling-v1", **kw),
                                  lambda **kw: gym.make_vec("MillVib-Valve-Rolling-v1", 2,
                                                            vectorization_mode="vector_entry_point", **kw)])
def test_a_per_task_id_refuses_an_episode_its_timelimit_would_cut(make):
    with pytest.raises(ValueError, match=r"episode_s = 2\.0 s gives 4000 steps, past max_episode_steps = 2000"):
        make(episode_s=2.0)
    make(episode_s=0.5)  # a shorter episode ends itself before the limit


def rollout(env, seed, actions):
    obs, info = env.reset(seed=seed)
    out = [obs]
    rewards = []
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return np.array(out), np.array(rewards), info


def test_an_env_config_built_once_is_taken_as_it_is_by_every_constructor(monkeypatch):
    """The four constructors build their engine through one builder (`envs.build`), and an EnvConfig built once at
    the edge is used as it is: no file is read, the environment is the one built from the config's name, and
    keyword overrides merge into a copy of it."""
    import millvib_env.envs.config as config_module
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.envs.vec_env import MillVibVecEnv
    from millvib_env.envs.vector import ValveVectorEnv

    cfg = load_env_config("rolling", version="v1")
    by_name = EpisodeBatch("MillVib-Valve-v1", 2, config="rolling")
    monkeypatch.setattr(config_module, "_read", lambda *a, **k: pytest.fail("a config file was read"))
    built = [gym.make("MillVib-Valve-v1", config=cfg).unwrapped, MillVibVecEnv("MillVib-Valve-v1", 2, config=cfg),
             ValveVectorEnv(2, config=cfg), EpisodeBatch("MillVib-Valve-v1", 2, config=cfg)]
    assert all(env.core.settings.cfg is cfg and env.config is cfg for env in built)
    assert np.array_equal(built[-1].reset([7, 8]), by_name.reset([7, 8]))
    a = np.full((2, 1), 0.3, dtype=np.float32)
    assert np.array_equal(built[-1].step(a)[0], by_name.step(a)[0])
    changed = EpisodeBatch("MillVib-Valve-v1", 1, config=cfg, reward={"w_effort": 0.5})
    assert changed.core.settings.cfg.reward.w_effort == 0.5 and cfg.reward.w_effort != 0.5
    with pytest.raises(ValueError, match="EnvConfig of version 'v1', not 'v0'"):
        EpisodeBatch("MillVib-Valve-v0", 1, config=cfg)
    with pytest.raises(ValueError, match="runs its own config"):
        EpisodeBatch("MillVib-Valve-Rolling-v1", 1, config=cfg)


def test_seeded_resets_reproduce_episodes_exactly():
    env = gym.make("MillVib-GainSchedule-v0")
    actions = np.random.default_rng(1).uniform(-1, 1, (60, 3))
    a = rollout(env, 123, actions)
    b = rollout(gym.make("MillVib-GainSchedule-v0"), 123, actions)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert a[2]["severity"] == b[2]["severity"]
    c = rollout(env, 124, actions)
    assert c[2]["params"]["c1"] != a[2]["params"]["c1"]


def test_c1_and_ct_spread_log_uniformly_over_their_ranges():
    venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 1, seed=7, monitor=False)
    core = venv.core
    core.seed_env(0, 7)  # reset_env below bypasses the VecEnv's pending seed
    c1, ct = [], []
    for _ in range(400):
        _, info = core.reset_env(0)
        c1.append(info["params"]["c1"])
        ct.append(info["params"]["Ct"])
    c1, ct = np.log(c1), np.log(ct)
    for values, lo, hi in ((c1, 1.25e5, 2.25e6), (ct, 5e-16, 5e-9)):
        assert values.min() >= np.log(lo) - 1e-12 and values.max() <= np.log(hi) + 1e-12
        u = (values - np.log(lo)) / (np.log(hi) - np.log(lo))
        assert stats.kstest(u, "uniform").pvalue > 0.01
    assert abs(np.corrcoef(c1, ct)[0, 1]) < 0.15  # drawn independently


def test_params_are_hidden_unless_asked_and_always_in_info():
    plain = gym.make("MillVib-GainSchedule-v0")
    ablation = gym.make("MillVib-GainSchedule-v0", observe_params=True)
    assert ablation.observation_space.shape[0] == plain.observation_space.shape[0] + 2
    _, info = plain.reset(seed=0)
    assert set(info["params"]) >= {"c1", "Ct"}
    _, _, _, _, info = plain.step(np.zeros(3))
    assert set(info["params"]) >= {"c1", "Ct"}


def test_reset_options_pin_parameters_and_load_scenarios():
    env = gym.make("MillVib-GainSchedule-v0")
    _, info = env.reset(seed=0, options={"params": {"c1": 3.0e5}})
    assert info["params"]["c1"] == 3.0e5
    from millvib_env.envs.scenarios import get_scenario

    for name in list_scenarios():
        _, info = env.reset(options={"scenario": name})
        assert info["scenario"] == name and info["disturbances"] == []
        expected = get_scenario(name).plant()
        assert info["params"]["c1"] == expected.c1 and info["params"]["Ct"] == expected.Ct
    with pytest.raises(ValueError, match="scenario"):
        env.reset(options={"scenario": "nope"})
    with pytest.raises(ValueError, match="MillParams.c1"):
        env.reset(options={"params": {"c1": -1.0}})


@pytest.mark.parametrize("env_id, kwargs", ENV_CASES)
def test_native_vec_env_equals_dummy_vec_env_over_single_envs(env_id, kwargs):
    n, seed = 4, 11
    native = millvib_env.make_vec_env(env_id, n, seed=seed, monitor=False, **kwargs)
    dummy = DummyVecEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n)])
    dummy.seed(seed)
    obs_n, obs_d = native.reset(), dummy.reset()
    np.testing.assert_allclose(obs_n, obs_d, rtol=1e-6, atol=1e-7)
    steps = 2 * native.get_attr("max_steps")[0] + 5  # two full episodes and an auto-reset
    rng = np.random.default_rng(3)
    shape = native.action_space.shape
    done_seen = 0
    for _ in range(steps):
        act = rng.uniform(-1, 1, (n, *shape)).astype(np.float32)
        on, rn, dn, inf_n = native.step(act)
        od, rd, dd, inf_d = dummy.step(act)
        np.testing.assert_allclose(on, od, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(rn, rd, rtol=1e-6, atol=1e-6)
        assert np.array_equal(dn, dd)
        for i in np.flatnonzero(dn):
            done_seen += 1
            np.testing.assert_allclose(inf_n[i]["terminal_observation"], inf_d[i]["terminal_observation"],
                                       rtol=1e-6, atol=1e-7)
            assert inf_n[i]["TimeLimit.truncated"] == inf_d[i]["TimeLimit.truncated"]
            assert inf_n[i]["severity"] == pytest.approx(inf_d[i]["severity"], rel=1e-9)
    assert done_seen >= 2 * n


@pytest.mark.parametrize("bad", [np.array([np.nan, 0, 0]), np.array([0, np.inf, 0]), np.zeros(2), np.zeros((2, 3)),
                                 [10 ** 400, 0, 0], "abc"])  # an integer beyond a float: found by a fuzz
def test_bad_actions_raise_clear_errors(bad):
    env = gym.make("MillVib-GainSchedule-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.unwrapped.step(bad)


def test_out_of_range_actions_are_clipped():
    env = gym.make("MillVib-Valve-v0").unwrapped
    env.reset(seed=0)
    a, *_ = env.step(np.array([5.0]))
    env.reset(seed=0)
    b, *_ = env.step(np.array([1.0]))
    assert np.array_equal(a, b)


@pytest.mark.parametrize("env_id", ["MillVib-GainSchedule-v0", "MillVib-Valve-v0"])
def test_random_actions_in_the_unstable_corner_never_give_nan(env_id):
    # low damping, high leakage, and actions pushed to their extremes (KP up to 1e7, full valve)
    venv = millvib_env.make_vec_env(env_id, 8, seed=5, monitor=False,
                                    randomize={"c1": {"dist": "loguniform", "low": 1.25e5, "high": 2.5e5},
                                               "Ct": {"dist": "loguniform", "low": 1e-10, "high": 5e-9}})
    venv.reset()
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(venv.get_attr("max_steps")[0] + 10):
        act = np.sign(rng.uniform(-1, 1, (8, *venv.action_space.shape)))
        obs, rew, done, infos = venv.step(act)
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rew))
        assert np.all(np.abs(obs) <= 1.0)
        for i in np.flatnonzero(done):
            ends += 1
            assert np.isfinite(infos[i]["severity"]) and np.isfinite(infos[i]["tracking_rms_um"])
    assert ends >= 8


def test_episode_end_info_has_the_metrics():
    env = gym.make("MillVib-GainSchedule-v0")
    env.reset(seed=2)
    while True:
        _, _, term, trunc, info = env.step(np.zeros(3))
        if term or trunc:
            break
    for key in ("severity", "tracking_rms_um", "iso_zone", "diverged", "params"):
        assert key in info
    assert info["iso_zone"] in "ABCD" and info["severity"] > 0


def test_render_rgb_array_gives_a_frame():
    env = gym.make("MillVib-GainSchedule-v0", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.zeros(3))
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8 and frame.std() > 0
    env.close()


def test_human_mode_paces_its_frames_to_render_fps(monkeypatch):
    """On a clock the test sets: a frame that comes early waits until 1/render_fps after the last one; a late one
    is shown at once (the shortest pause) and the next is due 1/render_fps after it."""
    import matplotlib.pyplot as plt

    from millvib_env.envs import rendering

    clock, pauses = [100.0], []
    monkeypatch.setattr(rendering.time, "perf_counter", lambda: clock[0])
    monkeypatch.setattr(plt, "pause", lambda s: pauses.append(s) or clock.__setitem__(0, clock[0] + s))
    env = gym.make("MillVib-GainSchedule-Rolling-v1", render_mode="human")
    fps = env.metadata["render_fps"]
    env.reset(seed=0)  # the first frame: shown at once
    env.step(np.zeros(3))  # drawn at once after it: it waits a whole frame
    clock[0] += 0.5  # late: shown at once
    env.step(np.zeros(3))
    assert pauses[0] == pytest.approx(1e-3) and pauses[1] == pytest.approx(1 / fps - 1e-3)
    assert pauses[2] == pytest.approx(1e-3)
    env.close()
    plt.close("all")


def test_record_video_wrapper_works(tmp_path):
    pytest.importorskip("moviepy")
    folder = tmp_path / "videos"
    env = gym.wrappers.RecordVideo(gym.make("MillVib-GainSchedule-v0", render_mode="rgb_array"), str(folder),
                                   episode_trigger=lambda k: k == 0)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros(3))
    env.close()
    assert list(folder.glob("*.mp4"))


def test_the_render_window_is_kept_only_where_a_render_mode_asks_and_the_steps_are_the_same():
    """The recent samples the render draws are kept where a render mode is set (or from a first render on), not
    at every step of every run; what the steps return does not depend on it."""
    from millvib_env.envs.vec_env import MillVibVecEnv

    plain = gym.make("MillVib-Valve-v1", residual=True)
    drawn = gym.make("MillVib-Valve-v1", residual=True, render_mode="rgb_array")
    assert not plain.unwrapped.core.keep_history and drawn.unwrapped.core.keep_history
    for env in (plain, drawn):
        env.reset(seed=4)
    for _ in range(6):
        a, b = plain.step(np.full(1, 0.2, np.float32)), drawn.step(np.full(1, 0.2, np.float32))
        assert np.array_equal(a[0], b[0]) and a[1:4] == b[1:4]
    assert len(plain.unwrapped.core.history[0]["t"]) == 1 and len(drawn.unwrapped.core.history[0]["t"]) == 7
    frame = drawn.render()
    assert frame.ndim == 3 and frame.shape[2] == 3
    venv = MillVibVecEnv("MillVib-Valve-v1", 2, residual=True)
    assert not venv.core.keep_history
    venv.set_attr("render_mode", "rgb_array")
    assert venv.core.keep_history


def test_config_errors_name_the_key():
    with pytest.raises(ValueError, match="episode_s"):
        gym.make("MillVib-GainSchedule-v0", episode_s=-1.0)
    with pytest.raises(ValueError, match="unknown env config"):
        gym.make("MillVib-GainSchedule-v0", episodes=3)
    with pytest.raises(ValueError, match="randomize"):
        gym.make("MillVib-GainSchedule-v0", randomize={"damping": {"low": 1, "high": 2}})


@pytest.mark.slow
def test_ppo_trains_on_the_native_vec_env():
    from stable_baselines3 import PPO

    venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 4, seed=0)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=2, seed=0, device="cpu")
    model.learn(total_timesteps=2048)
    action, _ = model.predict(venv.reset(), deterministic=True)
    assert action.shape == (4, 3) and np.all(np.abs(action) <= 1)


def test_gain_changes_are_bumpless_in_the_integral_term():
    from millvib_env.plant.model import A_U, IUI, IV, IX

    env = gym.make("MillVib-GainSchedule-v0", config="paper").unwrapped
    env.reset(seed=0)
    core = env.core
    env.step(np.array([0.2, 0.8, 0.0]))  # a large KI: the integral term builds up
    g_old = core.gains[0].copy()
    y_end = core.Y[0].copy()
    u_end = core.AUXS[0, -1, A_U]
    assert abs(y_end[IUI]) > 1e-3
    env.step(np.array([-0.5, -1.0, 0.5]))  # new gains, KI to its minimum
    g_new = core.gains[0]
    u_start = core.AUXS[0, 0, A_U]  # the command right after the change
    e, v = -y_end[IX], y_end[IV]
    assert core.YS[0, 0, IUI] == y_end[IUI]  # the integral term carries over unchanged
    expected_jump = (g_new[0] - g_old[0]) * e - (g_new[2] - g_old[2]) * v
    assert u_start - u_end == pytest.approx(expected_jump, rel=1e-9, abs=1e-9)


def test_realistic_config_adds_noise_delay_and_eccentricity():
    env = gym.make("MillVib-GainSchedule-v0", config="realistic").unwrapped
    obs0, info = env.reset(seed=4)
    assert env.core.observer.delay == 1 and env.core.observer.noise is not None
    from millvib_env.plant.model import C_EA

    assert env.core.C[0, C_EA] == env.core.profiles[0].ecc_amp_n > 0.0  # an eccentricity force was drawn
    first, *_ = env.step(np.zeros(3))
    assert np.array_equal(first, obs0)  # one-step delay: the first step shows the reset observation
    second, *_ = env.step(np.zeros(3))
    assert not np.array_equal(second, first)
    quiet = gym.make("MillVib-GainSchedule-v0", config="realistic", disturbances={"sensor_noise": None}).unwrapped
    quiet.reset(seed=4)
    assert quiet.core.observer.noise is None and quiet.params == env.params  # same plant, noise off


def test_episodes_that_end_together_are_scored_as_one_at_a_time():
    # the unstable corner: episodes end together (truncated) and apart (diverged, records of many
    # lengths, some shorter than the 0.1 s split); the batched metrics are the single ones
    venv = millvib_env.make_vec_env("MillVib-GainSchedule-v0", 8, seed=5, monitor=False, episode_s=0.2,
                                    randomize={"c1": {"dist": "loguniform", "low": 1.25e5, "high": 2.5e5},
                                               "Ct": {"dist": "loguniform", "low": 1e-10, "high": 5e-9}})
    core = venv.core
    venv.reset()
    rng = np.random.default_rng(0)
    lengths, diverged = set(), 0
    for _ in range(300):
        _, _, term, trunc, infos = core.step(np.sign(rng.uniform(-1, 1, (8, 3))))
        for i in np.flatnonzero(term | trunc):
            single = core.episode_metrics(i, bool(term[i]))
            for key, value in single.items():
                if isinstance(value, float):
                    assert infos[i][key] == pytest.approx(value, rel=1e-12), key
                else:
                    assert infos[i][key] == value, key
            lengths.add(int(core.n_trace[i]))
            diverged += bool(term[i])
            core.reset_env(i)
    assert diverged >= 5 and len(lengths) >= 4 and min(lengths) < 1001


@pytest.mark.parametrize("n_samp, spp", [(10, 10), (100, 10), (300, 10)])
def test_the_period_summary_is_the_libraries_arithmetic(n_samp, spp):
    # the compiled pass (envs.period) against scipy's sosfilt and numpy's mean, filter states carried
    from scipy import signal as ssig

    from millvib_env.envs.period import pairwise_sum, summarize_period
    from millvib_env.plant.model import A_ACC, IPL, IV, IX, NAUX, NY

    rng = np.random.default_rng(0)
    sos = np.ascontiguousarray(ssig.butter(2, (10, 1000), btype="bandpass", fs=1e4, output="sos"))
    n = 5
    zi_ref, zi = np.zeros((sos.shape[0], n, 2)), np.zeros((n, sos.shape[0], 2))
    acc_trace, n_trace = np.zeros((n, 20 * n_samp)), np.zeros(n, dtype=np.int64)
    for period in range(20):
        ys = rng.normal(size=(n, n_samp + 1, NY)) * 10.0 ** rng.uniform(-6, 2)
        aux = rng.normal(size=(n, n_samp + 1, NAUX))
        xd = rng.normal(size=(n, n_samp // spp))
        out = [np.zeros(n) for _ in range(5)]
        summarize_period(ys, aux, xd, spp, sos, zi, acc_trace, n_trace, *out)
        v_band, zi_ref = ssig.sosfilt(sos, ys[:, 1:, IV], axis=1, zi=zi_ref)
        e = np.repeat(xd, spp, axis=1) - ys[:, 1:, IX]
        np.testing.assert_allclose(out[0], np.mean(v_band**2, axis=1), rtol=1e-12)
        np.testing.assert_allclose(out[1], np.mean(e**2, axis=1), rtol=1e-12)
        assert np.array_equal(out[2], np.abs(ys[:, 1:, IX]).max(axis=1))
        assert np.array_equal(out[3], ys[:, 1:, IPL].min(axis=1)) and np.array_equal(out[4], ys[:, 1:, IPL].max(axis=1))
        assert np.array_equal(acc_trace[:, period * n_samp:(period + 1) * n_samp], aux[:, 1:, A_ACC])
    np.testing.assert_allclose(zi, zi_ref.transpose(1, 0, 2), rtol=1e-12, atol=1e-300)
    assert np.all(n_trace == 20 * n_samp)
    for size in (1, 7, 8, 9, 127, 128, 129, 1000, 5001):
        a = rng.uniform(0, 1, size)
        assert pairwise_sum(a, size) == pytest.approx(np.sum(a), rel=1e-14)


def test_the_actuator_record_is_numpys_over_the_samples_written():
    # the compiled record (envs.period.record_actuator) against numpy's: maxima and counts are exact
    from millvib_env.envs.period import record_actuator
    from millvib_env.plant.model import A_QL, A_U, A_XV, NAUX

    rng = np.random.default_rng(1)
    n, n_samp = 6, 40
    rec = np.tile([0.0, 0.0, 0.0, 0.0, 0.0, np.inf, -np.inf], (n, 1))
    ref = rec.copy()
    u_max = np.full(n, 10.0)
    for _ in range(5):
        aux = rng.normal(size=(n, n_samp + 1, NAUX)) * 8.0
        n_valid = rng.integers(0, n_samp + 2, n)  # a period cut short anywhere, or whole
        pl_lo, pl_hi = rng.normal(size=n), rng.normal(size=n) + 3.0
        record_actuator(aux, n_valid, u_max, pl_lo, pl_hi, rec)
        valid = np.arange(1, n_samp + 1)[None, :] < n_valid[:, None]
        u = np.where(valid, np.abs(aux[:, 1:, A_U]), 0.0)
        ref[:, 0] = np.maximum(ref[:, 0], u.max(axis=1))
        ref[:, 1] += np.sum(valid & (u >= u_max[:, None]), axis=1)
        ref[:, 2] += valid.sum(axis=1)
        ref[:, 3] = np.maximum(ref[:, 3], np.where(valid, np.abs(aux[:, 1:, A_XV]), 0.0).max(axis=1))
        ref[:, 4] = np.maximum(ref[:, 4], np.where(valid, np.abs(aux[:, 1:, A_QL]), 0.0).max(axis=1))
        ref[:, 5], ref[:, 6] = np.minimum(ref[:, 5], pl_lo), np.maximum(ref[:, 6], pl_hi)
        assert np.array_equal(rec, ref)
    aux[0, 1, A_U] = np.nan  # a NaN is kept, as numpy's maximum keeps it
    record_actuator(aux, np.full(n, n_samp + 1), u_max, pl_lo, pl_hi, rec)
    assert np.isnan(rec[0, 0]) and not np.isnan(rec[1:, 0]).any()


def test_sensor_noise_drawn_ahead_is_one_draw_per_observation_from_the_episodes_stream():
    from millvib_env.envs.disturbances import SensorNoise
    from millvib_env.envs.observation import Observer

    noise = SensorNoise(x_m=5e-7, v_m_s=1e-4, a_m_s2=0.5)
    obs = Observer("valve", residual=False, gain_names=("KP",), observe_phase=False, observe_params=False,
                   noise=noise, delay=0, n=3)
    rows = 4
    for i in range(3):
        obs.start_noise(i, np.random.default_rng(100 + i), rows)
    got = [obs._noise(np.array([0, 2])) for _ in range(rows + 3)]  # past the block: from the stream itself
    got += [obs._noise(np.array([1]))]
    ref = {i: np.random.default_rng(100 + i) for i in range(3)}
    want = [np.stack([noise.sample(ref[i], 1)[0] for i in (0, 2)]) for _ in range(rows + 3)]
    want += [noise.sample(ref[1], 1)]
    for g, w in zip(got, want):
        assert np.array_equal(g, w)


@pytest.mark.parametrize("mode", ["SameStep", "NextStep"])
def test_gymnasiums_vector_entry_point_equals_sync_vector_env_over_single_envs(mode):
    """gym.make_vec(id, n, vectorization_mode="vector_entry_point") is the batched engine behind Gymnasium's
    VectorEnv: step for step (through two episode ends) the same observations, rewards, ends, final observations
    and infos as SyncVectorEnv over n single environments, in either auto-reset mode (next-step the default, as
    Gymnasium's: the restart's step has reward 0 and no end); a bad mode is refused in one line."""
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    n, kw, reset_mode = 3, {"config": "startup"}, AutoresetMode(mode)
    given = {} if reset_mode == AutoresetMode.NEXT_STEP else {"autoreset_mode": reset_mode}
    fast = gym.make_vec("MillVib-GainSchedule-v1", n, vectorization_mode="vector_entry_point", **given, **kw)
    slow = gym.make_vec("MillVib-GainSchedule-v1", n, vectorization_mode="sync",
                        vector_kwargs={"autoreset_mode": reset_mode}, **kw)
    assert fast.metadata["autoreset_mode"] == slow.metadata["autoreset_mode"] == reset_mode
    assert fast.single_action_space == slow.single_action_space and fast.observation_space == slow.observation_space
    (o1, i1), (o2, i2) = fast.reset(seed=7), slow.reset(seed=7)
    np.testing.assert_array_equal(o1, o2)
    assert sorted(i1) == sorted(i2)
    rng, ends, ended = np.random.default_rng(0), 0, np.zeros(n, bool)
    for _ in range(103):
        a = rng.uniform(-1, 1, fast.action_space.shape).astype(np.float32)
        got, want = fast.step(a), slow.step(a)
        for x, y in zip(got[:4], want[:4]):
            np.testing.assert_array_equal(x, y)
        assert sorted(got[4]) == sorted(want[4])
        np.testing.assert_array_equal(got[4]["params"]["c1"], want[4]["params"]["c1"])
        if reset_mode == AutoresetMode.NEXT_STEP:
            assert np.all(got[1][ended] == 0.0) and not np.any((got[2] | got[3])[ended])  # the restart's step
        ended = got[2] | got[3]
        ends += int(np.any(ended))
        if "final_obs" in got[4]:
            done = got[4]["_final_obs"]
            np.testing.assert_array_equal(done, want[4]["_final_obs"])
            np.testing.assert_array_equal(np.stack(got[4]["final_obs"][done]), np.stack(want[4]["final_obs"][done]))
    assert ends == 2
    with pytest.raises(ValueError, match="seed"):
        fast.reset(seed=[1, 2])
    with pytest.raises(ValueError, match="autoreset_mode = 'later' is invalid"):
        gym.make_vec("MillVib-GainSchedule-v1", 2, vectorization_mode="vector_entry_point", autoreset_mode="later")


def test_gymnasiums_vector_wrappers_run_on_the_vector_entry_point_of_every_id():
    import gymnasium as gym
    from gymnasium.wrappers.vector import NormalizeObservation, RecordEpisodeStatistics

    from millvib_env.envs.specs import ENV_SPECS

    for env_id in ENV_SPECS:
        env = RecordEpisodeStatistics(NormalizeObservation(
            gym.make_vec(env_id, 2, vectorization_mode="vector_entry_point")))
        obs, _ = env.reset(seed=0)
        for _ in range(3):
            obs, *_ = env.step(np.zeros(env.action_space.shape, np.float32))
        assert obs.shape == env.observation_space.shape and np.all(np.isfinite(obs))
    env = RecordEpisodeStatistics(gym.make_vec("MillVib-GainSchedule-v1", 2, vectorization_mode="vector_entry_point"))
    env.reset(seed=0)
    for _ in range(60):
        _, _, term, trunc, info = env.step(np.zeros(env.action_space.shape, np.float32))
        if np.any(term | trunc):
            assert np.all(info["episode"]["l"][info["_episode"]] > 0)
            break
    else:
        raise AssertionError("no startup episode ended within 60 decisions")


def test_every_task_config_has_its_own_id_that_runs_the_same_episodes():
    """MillVib-<Name>-<Config>-<version> (for clients that take an id string only) is the generic id with that
    config: the same first observations from gym.make, the SB3 VecEnv and Gymnasium's vector entry point; it
    refuses another config; Gymnasium's registry holds exactly the ids of envs.specs.ENV_SPECS, as they say."""
    from millvib_env import make_vec_env
    from millvib_env.envs.batch import ID_CONFIGS
    from millvib_env.envs.specs import ENV_SPECS

    assert set(ENV_SPECS) == {i for i in gym.registry if i.startswith("MillVib-")}
    for env_id, spec in ENV_SPECS.items():
        reg = gym.registry[env_id]
        assert (reg.entry_point, reg.vector_entry_point, reg.kwargs) == \
            (spec.entry_point, spec.vector_entry_point, spec.kwargs)
    assert set(ID_CONFIGS) == {i for i in gym.registry if i.startswith("MillVib-") and i.count("-") == 3}
    for env_id, config in ID_CONFIGS.items():
        if not env_id.endswith("-v1"):
            continue
        generic = env_id.replace(f"-{config.capitalize()}-", "-")
        own, _ = gym.make(env_id).reset(seed=3)
        same, _ = gym.make(generic, config=config).reset(seed=3)
        np.testing.assert_array_equal(own, same)
        np.testing.assert_array_equal(make_vec_env(env_id, 2, seed=3).reset(),
                                      make_vec_env(generic, 2, seed=3, config=config).reset())
        vec, _ = gym.make_vec(env_id, 2, vectorization_mode="vector_entry_point").reset(seed=3)
        np.testing.assert_array_equal(vec, gym.make_vec(generic, 2, vectorization_mode="vector_entry_point",
                                                        config=config).reset(seed=3)[0])
        other = "startup" if config != "startup" else "rolling"
        with pytest.raises(ValueError, match="contradicts"):
            make_vec_env(env_id, 1, config=other)


class _CoilWeld:
    """The manual's example: a 5 % force bump for 20 ms at a random time (docs/environments.md)."""

    def apply(self, rng, profile, params):
        k = int(rng.uniform(0.1, 0.4) / profile.dt)
        profile.dFL[k:k + int(0.02 / profile.dt)] += 0.05 * params.FL
        profile.events.append(("weld", k * profile.dt, 0.05 * params.FL))


class _Poison:
    def apply(self, rng, profile, params):
        profile.xd[3] = np.nan


@pytest.mark.parametrize("env_id", ["MillVib-GainSchedule-v1", "MillVib-Valve-v0"])
def test_a_users_disturbance_runs_after_the_configs_and_leaves_their_draws_as_they_were(env_id):
    from millvib_env.envs.disturbances import Disturbance

    assert isinstance(_CoilWeld(), Disturbance)
    plain = gym.make(env_id, config="rolling")
    welded = gym.make(env_id, config="rolling", extra_disturbances=[_CoilWeld()])
    _, info_plain = plain.reset(seed=7)
    _, info_welded = welded.reset(seed=7)
    a, b = plain.unwrapped.core, welded.unwrapped.core
    weld = [e for e in info_welded["disturbances"] if e[0] == "weld"]
    assert len(weld) == 1 and info_welded["disturbances"][:-1] == info_plain["disturbances"]
    assert np.array_equal(a.XD[0], b.XD[0]) and a.params[0] == b.params[0]  # the config's draws, unchanged
    bump = b.DFL[0] - a.DFL[0]
    dt = b.settings.cfg.control_dt_s
    k = int(round(weld[0][1] / dt))
    assert bump[k] == pytest.approx(0.05 * b.params[0].FL) and np.count_nonzero(bump) == int(0.02 / dt)
    action = plain.action_space.sample() * 0.0
    for _ in range(3):
        plain.step(action)
        welded.step(action)
    # the same through the VecEnv
    venv = millvib_env.make_vec_env(env_id, 2, seed=7, config="rolling", extra_disturbances=[_CoilWeld()])
    venv.reset()
    assert np.array_equal(venv.unwrapped.core.DFL[0], b.DFL[0])


def test_a_users_disturbance_that_is_no_disturbance_or_writes_nan_is_refused_in_one_line():
    with pytest.raises(ValueError, match=r"extra_disturbances\[0\]") as info:
        gym.make("MillVib-GainSchedule-v1", extra_disturbances=[object()])
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="extra_disturbances = "):
        gym.make("MillVib-GainSchedule-v1", extra_disturbances=_CoilWeld())
    env = gym.make("MillVib-GainSchedule-v1", extra_disturbances=[_Poison()])
    with pytest.raises(ValueError, match=r"profile\.xd") as info:
        env.reset(seed=0)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("env_id", ["MillVib-GainSchedule-v1", "MillVib-Valve-v1"])
def test_a_users_reward_replaces_the_configs_and_leaves_the_observations_as_they_were(env_id):
    seen = []

    def quiet_first(terms):
        seen.append(terms)
        return -terms.vibration_rms_m_s * 1e3 - 100.0 * terms.terminated

    plain = gym.make(env_id, config="rolling")
    own = gym.make(env_id, config="rolling", reward_fn=quiet_first)
    obs_a, _ = plain.reset(seed=3)
    obs_b, _ = own.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(4):
        action = rng.uniform(-0.3, 0.3, plain.action_space.shape).astype(np.float32)
        obs_a, r_a, *_ = plain.step(action)
        obs_b, r_b, *_ = own.step(action)
        assert np.array_equal(obs_a, obs_b)
        assert r_b == pytest.approx(-seen[-1].vibration_rms_m_s[0] * 1e3) and r_a == seen[-1].config_reward[0]
        assert r_a != r_b


@pytest.mark.parametrize("bad", [lambda terms: np.nan, lambda terms: "x", lambda terms: [1.0, 2.0]])
def test_a_users_reward_that_is_not_one_finite_number_per_env_is_refused_in_one_line(bad):
    env = gym.make("MillVib-GainSchedule-v1", reward_fn=bad)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="reward_fn") as info:
        env.step(env.action_space.sample() * 0)
    assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="reward_fn = 3"):
        gym.make("MillVib-GainSchedule-v1", reward_fn=3)


def test_a_users_envelope_ends_an_episode_as_the_configs_does_and_is_checked():
    calls = []

    def at_step_three(terms):
        calls.append(terms)
        return terms.t_s > 2.5 * 0.01  # GainSchedule-v1: 10 ms agent periods

    plain = gym.make("MillVib-GainSchedule-v1", config="rolling")
    own = gym.make("MillVib-GainSchedule-v1", config="rolling", envelope_fn=at_step_three)
    plain.reset(seed=5)
    own.reset(seed=5)
    action = plain.action_space.sample() * 0
    for k in range(3):
        obs_a, _, term_a, _, info_a = plain.step(action)
        obs_b, _, term_b, _, info_b = own.step(action)
        assert np.array_equal(obs_a, obs_b) and not term_a
        assert term_b == (k == 2) and not calls[-1].left_config[0]
    assert info_b["diverged"] and info_b["episode_steps"] == 3 and "diverged" not in info_a
    for bad in (lambda terms: "yes", lambda terms: [True, False], lambda terms: 0.5):
        env = gym.make("MillVib-GainSchedule-v1", envelope_fn=bad)
        env.reset(seed=0)
        with pytest.raises(ValueError, match="envelope_fn") as info:
            env.step(action)
        assert "\n" not in str(info.value)
    with pytest.raises(ValueError, match="envelope_fn = 'no'"):
        gym.make("MillVib-GainSchedule-v1", envelope_fn="no")


def test_a_base_controller_object_runs_as_its_named_gain_set_in_every_kind_of_env():
    """``base_controller=`` (a `LoopController`: a PIDGains or a fixed-gain baseline) is the controller under the
    action: the residual valve action's or the relative gain action's base. Its episodes are, bit for bit, those of
    its gains given in the config; the zero gain action is exactly the controller's benchmark episode."""
    from millvib_env import PIDGains
    from millvib_env.catalog.factory import load_controller
    from millvib_env.envs.vec_env import MillVibVecEnv
    from millvib_env.envs.vector import ValveVectorEnv
    from millvib_env.evaluation.evaluate import run_episodes

    ctrl = load_controller("pid-pf-robust", version="v1")

    def valve_course(env, steps=60):
        obs, _ = env.reset(seed=20011)
        seen = [obs]
        for _ in range(steps):
            obs, *_ = env.step(np.full(env.action_space.shape, 0.05, np.float32))
            seen.append(obs)
        return np.array(seen)

    by_name = valve_course(gym.make("MillVib-Valve-v1", residual=True, actions={"residual_gains": "pid-pf-robust"}))
    for base in (ctrl, PIDGains(*ctrl.loop_gains())):
        assert np.array_equal(valve_course(gym.make("MillVib-Valve-v1", residual=True, base_controller=base)), by_name)
    vec = MillVibVecEnv("MillVib-Valve-v1", 2, residual=True, base_controller=ctrl)
    assert vec.core.settings.residual_gains == PIDGains(*ctrl.loop_gains())
    vector = ValveVectorEnv(2, env_version="v1", residual=True, base_controller=ctrl)
    assert vector.core.settings.residual_gains == vec.core.settings.residual_gains

    seed = 20000 + 3
    env = gym.make("MillVib-GainSchedule-v1", base_controller=ctrl)
    assert env.action_space.shape == (4,)
    env.reset(seed=seed)
    done = False
    while not done:
        _, _, term, trunc, info = env.step(np.zeros(4, np.float32))
        done = term or trunc
    expected = run_episodes(ctrl, [seed], task="startup")[0]
    assert (info["severity"], info["tracking_rms_um"]) == (expected["severity_mm_s"], expected["tracking_rms_um"])


def test_a_base_controller_that_the_loop_cannot_run_is_refused_in_one_line():
    from millvib_env.catalog.factory import load_controller

    ctrl = load_controller("pid-pf-robust", version="v1")
    cases = [(dict(residual=True, base_controller=load_controller("pid-oracle", version="v1")), "loop_gains"),
             (dict(residual=True, base_controller=3), "base_controller = 3"),
             (dict(residual=True, base_controller=ctrl, actions={"residual_gains": [1.0, 0.0, 0.0]}), "both given"),
             (dict(base_controller=ctrl), "residual = False")]
    for kwargs, what in cases:
        with pytest.raises(ValueError, match=what) as info:
            gym.make("MillVib-Valve-v1", **kwargs)
        assert "\n" not in str(info.value)

    class Broken:
        def loop_gains(self):
            return [1.0, float("nan"), 0.0]

    class Raises:
        def loop_gains(self):
            raise TypeError("no gains here")

    for bad in (Broken(), Raises()):
        with pytest.raises(ValueError, match="3 to 5 finite gains") as info:
            gym.make("MillVib-GainSchedule-v1", base_controller=bad)
        assert "\n" not in str(info.value)


def test_an_env_config_is_immutable_and_still_pickles_and_copies():
    """One EnvConfig is shared by every caller that loads it (`Task.env_config`): no section or list of it can be
    changed in place; it still pickles (jobs in other processes), and a deep copy is a plain dict to change."""
    import copy
    import pickle

    from millvib_env.tasks import get_task

    cfg = get_task("rolling").configs["v1"]
    for change in (lambda: cfg.raw.__setitem__("episode_s", 2.0), lambda: cfg.raw["reward"].update(w_effort=1.0),
                   lambda: cfg.raw["observation"].pop("force"), lambda: cfg.raw["disturbances"].clear()):
        with pytest.raises(TypeError, match="frozen"):
            change()
    assert get_task("rolling").configs["v1"].raw == cfg.raw
    mine = copy.deepcopy(cfg.raw)
    mine["reward"]["w_effort"] = 1.0
    assert type(mine) is dict and mine != cfg.raw
    back = pickle.loads(pickle.dumps(cfg))
    assert back.raw == cfg.raw and back.observation == cfg.observation and back.base_params == cfg.base_params
    with pytest.raises(TypeError, match="frozen"):
        back.raw["reward"]["w_effort"] = 1.0


def test_the_engines_settings_are_one_frozen_object_apart_from_its_state():
    """What a batch is (`envs.core_settings.CoreSettings`: its size, mode, config, clock, action range, envelope)
    lives in `core.settings` alone, frozen, as gymnax keeps its EnvParams apart from its EnvState: the core holds
    none of those names itself, and nothing changes them once the batch is made."""
    import dataclasses

    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.envs.core_settings import CoreSettings

    core = EpisodeBatch("MillVib-Valve-v1", 2, config="rolling", residual=True).core
    assert isinstance(core.settings, CoreSettings)
    names = {f.name for f in dataclasses.fields(CoreSettings)}
    assert not names & set(vars(core)), sorted(names & set(vars(core)))
    with pytest.raises(dataclasses.FrozenInstanceError):
        core.settings.max_steps = 1  # type: ignore[misc]
    s = core.settings
    assert (s.n, s.mode, s.residual) == (2, "valve", True) and s.n_samp == s.n_sub * s.spp
    assert s.n_ctrl == s.max_steps * s.n_sub and s.trace_samples == s.max_steps * s.n_samp + 1
