"""The MPC bounds (`control.mpc`) and the room they measure (`evaluation.benchmark.room`)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from millvib_env.analysis.linear import linearize
from millvib_env.catalog.factory import load_controller
from millvib_env.tasks import get_task
from millvib_env.control.mpc import MPCPolicy, MPCSettings, mpc_model
from millvib_env.plant.model import C_DFL, NY, STATE_NAMES, drive_vector, pack, plant_rhs
from millvib_env.params import PIDGains
from millvib_env.evaluation.benchmark import room
from millvib_env.evaluation.evaluate import run_episodes

SHORT = {"episode_s": 0.1}


def _rhs(params, y, c):
    dy, aux = np.zeros(NY), np.zeros(16)
    plant_rhs(0.0, y, pack(params.replace(pulse_amp=0.0)), c, dy, aux)
    return dy


def test_the_disturbance_columns_are_the_plants_own_response():
    """E's force column is -1/mt in the acceleration and nothing else: the force balance (8) of plant_rhs."""
    params = get_task("rolling").configs["v1"].base_params
    ss = linearize(params, 0.0, friction="sliding")
    assert ss.E.shape == (len(ss.states), 2)
    iv = ss.states.index("v")
    assert ss.E[iv, 0] == pytest.approx(-1.0 / params.mt, rel=1e-6)
    assert np.all(ss.E[[i for i in range(len(ss.states)) if i != iv], 0] == 0.0)
    # a rise of the supply pressure feeds the chamber while the port is open towards it (u0 > 0 holds the leak)
    ip = ss.states.index("pL")
    c = drive_vector(PIDGains(0.0), xd=0.0, u_ext=ss.u0, pid_on=False)
    assert ss.u0 > 0 and ss.E[ip, 1] > 0
    c[C_DFL] = 1e3  # the column is the derivative of the one right-hand side
    y0 = ss.op.y
    keep = [STATE_NAMES.index(n) for n in ss.states]
    slope = (_rhs(params, y0, c) - _rhs(params, y0, drive_vector(PIDGains(0.0), xd=0.0, u_ext=ss.u0,
                                                                      pid_on=False)))[keep] / 1e3
    np.testing.assert_allclose(slope, ss.E[:, 0], rtol=1e-6, atol=1e-12)


def test_the_condensed_qp_is_the_model_stepped():
    """The QP's gradient is the stepped model's: for random start states, commands, disturbances and set-points,
    the derivative of the cost of stepping (Ad, Bd, Ed) sample by sample (stage weights, the command and move
    penalties, the terminal weight) is 2 (H U + G_s s0 + G_e e + G_u u_held)."""
    from millvib_env.control.mpc import U_SCALE_V

    params = get_task("rolling").configs["v1"].base_params
    st = MPCSettings(horizon=6, q_x=2.0, q_v=0.5, q_i=0.1, r=0.01, r_d=0.2, residual_filter=0.0)
    m = mpc_model(params, st, 5e-4, 0.0)
    N, ns = 6, len(m.keep) + 1
    rng = np.random.default_rng(0)
    scale = np.array([1e-5, 1e-3, 1e5, 1e-5, 1e-2, 1e-7])[-ns:] if ns == 6 else np.ones(ns) * 1e-6
    rd = st.r_d / U_SCALE_V ** 2
    r = st.r / U_SCALE_V ** 2

    def cost(s0, U, e, held):
        s, J = s0.copy(), 0.0
        for j in range(N):
            s = m.Ad @ s + m.Bd * U[j] + m.Ed @ e[j]
            d = s.copy()
            d[0] -= e[j, 2]  # the tracking error: x - xd at the step's end
            J += d @ (m.P if j == N - 1 else 0.0 * m.Q) @ d + d @ m.Q @ d
            J += r * U[j] ** 2 + rd * (U[j] - (held if j == 0 else U[j - 1])) ** 2
        return J

    for _ in range(3):
        s0 = rng.normal(size=ns) * scale
        U = rng.normal(size=N) * 3.0
        e = rng.normal(size=(N, 3)) * np.array([1e5, 1e5, 1e-5])
        held = 0.7
        g = 2.0 * (m.H @ U + m.G_s @ s0 + m.G_e @ e.reshape(-1) + m.G_u * held)
        h = 1e-2
        num = np.array([(cost(s0, U + h * np.eye(N)[j], e, held) - cost(s0, U - h * np.eye(N)[j], e, held)) / (2 * h)
                        for j in range(N)])
        np.testing.assert_allclose(g, num, rtol=1e-6, atol=1e-9 * np.max(np.abs(num)))


@pytest.mark.parametrize("q_i", [0.0, 0.1])
@pytest.mark.parametrize("task", ["rolling", "varied"])
def test_the_horizons_tail_is_the_one_chosen_on_every_plant(task, q_i):
    """The tail P is the one `MPCSettings.tail` names on every plant, never a fallback. "riccati": P solves the
    discrete Riccati equation of the stage weights on the model; with no weight on the integral xi (q_i 0, every
    shipped bound), on the plant's states, xi's row and column zero (xi feeds nothing back). Solved on the whole
    model, that equation has xi's eigenvalue on the unit circle: the tail fell back to Q on most plants and not on
    others. "stage" (the default): Q."""
    from millvib_env.control.mpc import U_SCALE_V
    from millvib_env.tuning.search import plants_of

    st = MPCSettings(horizon=4, q_x=10.0, q_v=0.3, q_i=q_i, r=1e-3)
    ric = MPCSettings(horizon=4, q_x=10.0, q_v=0.3, q_i=q_i, r=1e-3, tail="riccati")
    for params in plants_of([1, 2, 3, 4], get_task(task)):
        assert np.array_equal(mpc_model(params, st, 5e-4, 0.0).P, mpc_model(params, st, 5e-4, 0.0).Q)
        m = mpc_model(params, ric, 5e-4, 0.0)
        k = len(m.keep) + (q_i > 0)
        A, B, Q, P = m.Ad[:k, :k], m.Bd[:k, None], m.Q[:k, :k], m.P[:k, :k]
        R = ric.r / U_SCALE_V ** 2
        riccati = A.T @ P @ A - P + Q - A.T @ P @ B @ np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        assert np.max(np.abs(riccati)) <= 1e-8 * np.max(np.abs(P))
        assert not np.allclose(m.P, m.Q)
        assert np.all(m.P[k:] == 0.0) and np.all(m.P[:, k:] == 0.0)


def test_a_model_is_built_with_blas_on_one_thread(monkeypatch):
    """BLAS's threads, woken by the condensed QP's products at every build, spun on the other core (a quarter of
    a benchmark's CPU time); the build runs with one, and the limit is lifted after it."""
    from threadpoolctl import threadpool_info

    import millvib_env.control.mpc as mpc

    seen = []
    build = mpc._build_model

    def watched(*args, **kwargs):
        seen.extend(lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas")
        return build(*args, **kwargs)

    monkeypatch.setattr(mpc, "_build_model", watched)
    before = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
    if not before:
        pytest.skip("no BLAS library that threadpoolctl can see")
    mpc_model(get_task("rolling").configs["v1"].base_params, MPCSettings(horizon=6), 5e-4, 0.0)
    assert seen and set(seen) == {1}
    assert [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"] == before


def test_mpc_respects_the_amplifier_and_the_loop():
    """Both bounds run on the valve of the sampled loop, never command beyond +-u_max, and every QP solves."""
    for name in ("mpc-oracle", "mpc-preview"):
        ctrl = load_controller(name, "rolling", version="v1")
        assert ctrl.env_id == "MillVib-Valve-v1"
        recs = run_episodes(ctrl, [120001, 120002], task="rolling", env_kwargs=SHORT)
        u_max = get_task("rolling").configs["v1"].base_params.u_max
        assert all(r["command_max_abs_v"] <= u_max for r in recs)
        assert not any(r["diverged"] for r in recs)
        assert ctrl.solves > 0 and ctrl.unsolved == 0


def test_mpc_refuses_what_it_cannot_run():
    with pytest.raises(ValueError, match="v1"):
        load_controller("mpc-oracle", "rolling", version="v0")
    ctrl = load_controller("mpc-oracle", "rolling", version="v1")
    with pytest.raises(ValueError, match="attach"):
        ctrl.predict(np.zeros(8, dtype=np.float32))
    with pytest.raises(ValueError, match="horizon"):
        MPCSettings(horizon=0)
    with pytest.raises(ValueError, match="residual_filter"):
        MPCSettings(residual_filter=2.0)
    gain_env_ctrl = MPCPolicy("mpc-oracle", MPCSettings())
    import gymnasium as gym
    env = gym.make("MillVib-GainSchedule-v1", config="rolling")
    with pytest.raises(ValueError, match="valve"):
        gain_env_ctrl.attach(env.unwrapped.core)


def _plain_episode(ctrl, env, seed: int) -> float:
    """One episode of `ctrl` in a plain Gymnasium loop; its return."""
    obs, _ = env.reset(seed=seed)
    done, ret = False, 0.0
    while not done:
        action, _ = ctrl.predict(obs)
        obs, reward, term, trunc, _ = env.step(action)
        ret += reward
        done = term or trunc
    return ret


def test_mpc_runs_in_a_plain_gymnasium_loop_as_in_the_benchmark():
    ctrl = load_controller("mpc-preview", "rolling", version="v1")
    ret = _plain_episode(ctrl, ctrl.make_env(**SHORT), 120001)
    rec = run_episodes(load_controller("mpc-preview", "rolling", version="v1"), [120001], task="rolling",
                       env_kwargs=SHORT)[0]
    assert rec["episode_return"] == pytest.approx(ret, rel=1e-9)


def _fake(costs: dict) -> dict:
    from millvib_env.evaluation.benchmark.protocol import summarize
    from millvib_env.evaluation.benchmark.comparison import _compare

    recs = {n: [{"seed": i, "cost": float(c), "severity_mm_s": 1.0, "tracking_rms_um": 1.0, "iso_zone": "A",
                 "diverged": False, "command_max_abs_v": 1.0, "command_at_limit_share": 0.0, "spool_stroke_m": 0.0,
                 "peak_flow_ratio": 0.0, "pl_min_pa": 0.0, "pl_max_pa": 1.0} for i, c in enumerate(v)]
            for n, v in costs.items()}
    result = {"reference": "pid-pf-robust", "records": recs, "controllers": {n: summarize(r) for n, r in recs.items()}}
    _compare(result)
    return result


def test_the_room_is_the_bounds_paired_gain_and_each_share_is_measured_against_it():
    rng = np.random.default_rng(1)
    base = rng.uniform(1.0, 2.0, 60)
    result = _fake({"pid-pf-robust": base, "pid-pf-ff": base * 0.95, "pid-pf-oracle": base * 0.99,
                    "mpc-oracle": base * 1.05, "mpc-preview": base * 0.6})
    r = room(result)
    assert r["rooms"] == {"without_preview": "pid-pf-oracle", "with_preview": "mpc-preview"}
    assert r["bounds"]["mpc-preview"]["room_mean"] == pytest.approx(0.4)
    assert r["bounds"]["mpc-oracle"]["room_mean"] == pytest.approx(-0.05)
    lo, hi = r["bounds"]["mpc-preview"]["room_mean_ci"]
    assert lo <= 0.4 <= hi
    assert r["shares"]["mpc-preview"]["with_preview"]["mean"]["score"] == pytest.approx(1.0)
    assert r["shares"]["pid-pf-ff"]["with_preview"]["mean"]["score"] == pytest.approx(0.125)
    assert "without_preview" not in r["shares"]["pid-pf-ff"]  # a room of 1 %: no shares
    assert r["best_deployable_classical"] == "pid-pf-ff"
    assert room({"reference": "pid-pf-robust", "records": {}, "controllers": {}}) is None


def test_the_preview_observation_is_the_episodes_own_course():
    """preview_samples adds, per look-ahead k, the force's and the set-point's change from the hold that starts
    now to the one k samples ahead, read from the episode's drawn course; bad look-aheads are refused."""
    import gymnasium as gym

    from millvib_env.envs.observation import OBS_SCALES, slog

    ks = [1, 4, 40]
    env = gym.make("MillVib-Valve-v1", config="rolling", observation={"preview_samples": ks})
    core = env.unwrapped.core
    names = core.obs_names
    assert names[-6:] == [f"preview_force_{k}" for k in ks] + [f"preview_setpoint_{k}" for k in ks]
    env.reset(seed=120003)
    for _ in range(250):
        obs, *_ = env.step(np.zeros(1))
    k = int(core.k[0])
    t = core.T[0]
    ecc = lambda tt: core._eccentricity(0, tt)  # noqa: E731
    for la in ks:
        df = core.DFL[0, k + la] + ecc(t + la * 5e-4) - core.DFL[0, k] - ecc(t)
        dxd = core.XD[0, k + la] - core.XD[0, k]
        assert obs[names.index(f"preview_force_{la}")] == pytest.approx(
            float(slog(np.array(df), *OBS_SCALES["load_force"][2:])), abs=1e-6)
        assert obs[names.index(f"preview_setpoint_{la}")] == pytest.approx(
            float(slog(np.array(dxd), *OBS_SCALES["error"][2:])), abs=1e-6)
    for bad in ([4, 2], [0], [1, 401], "3"):
        with pytest.raises(ValueError, match="preview_samples"):
            gym.make("MillVib-Valve-v1", config="rolling", observation={"preview_samples": bad})



def test_the_history_observation_is_the_measured_channels_k_steps_ago():
    """history_samples appends, per lag k, the measured channels as the agent saw them k steps earlier (the
    episode's first observation before it), in the batched engine as in one environment; bad lags are refused."""
    import gymnasium as gym

    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.envs.observation import HISTORY_CHANNELS

    lags = [1, 3]
    kw = {"residual": True, "observation": {"force": True, "history_samples": lags}}
    env = gym.make("MillVib-Valve-v1", config="rolling", **kw)
    names = env.unwrapped.core.obs_names
    now = [nm for nm in names if nm in HISTORY_CHANNELS]
    assert now == list(HISTORY_CHANNELS)
    assert names[-2 * len(now):] == [f"{nm}_lag_{k}" for k in lags for nm in now]
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (12, 1)).astype(np.float32)
    seen = [env.reset(seed=120004)[0]]
    for a in actions:
        seen.append(env.step(a)[0])
    seen = np.array(seen)
    cols = [names.index(nm) for nm in now]
    for k in lags:
        lagged = seen[:, [names.index(f"{nm}_lag_{k}") for nm in now]]
        past = np.concatenate([np.repeat(seen[:1, cols], k, axis=0), seen[:-k, cols]])
        np.testing.assert_array_equal(lagged, past)
    batch = EpisodeBatch("MillVib-Valve-v1", 2, config="rolling", **kw)
    out = [batch.reset([120004, 120005])[0]]
    for a in actions:
        out.append(batch.step(np.repeat(a[None], 2, axis=0))[0][0])
    np.testing.assert_array_equal(np.array(out), seen)  # the same engine: the same bytes
    for bad in ([3, 1], [0], [1, 257], "3"):
        with pytest.raises(ValueError, match="history_samples"):
            gym.make("MillVib-Valve-v1", config="rolling", observation={"history_samples": bad})

def test_the_memory_observation_is_each_channels_moving_averages():
    """history_filters appends, per time constant tau, the measured channels' exponential moving averages and
    those of their squares (each moves by 1/tau a step, started at the episode's first observation), after the
    lags, in the batched engine as in one environment; bad time constants are refused."""
    import gymnasium as gym

    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.envs.observation import HISTORY_CHANNELS

    taus = [2, 16]
    kw = {"residual": True, "observation": {"force": True, "history_samples": [1], "history_filters": taus}}
    env = gym.make("MillVib-Valve-v1", config="rolling", **kw)
    names = env.unwrapped.core.obs_names
    now = list(HISTORY_CHANNELS)
    assert names[-4 * len(now):] == [f"{nm}_{what}_{t}" for what in ("mean", "meansq") for t in taus for nm in now]
    assert names[-5 * len(now):-4 * len(now)] == [f"{nm}_lag_1" for nm in now]
    actions = np.random.default_rng(0).uniform(-1, 1, (30, 1)).astype(np.float32)
    seen = [env.reset(seed=120004)[0]]
    for a in actions:
        seen.append(env.step(a)[0])
    seen = np.array(seen, dtype=np.float64)
    x = seen[:, [names.index(nm) for nm in now]]
    for tau in taus:
        mean, meansq = x[0].copy(), x[0] ** 2
        for k in range(1, len(x)):  # float32 in the env: within its rounding over 30 steps
            mean += (x[k] - mean) / tau
            meansq += (x[k] ** 2 - meansq) / tau
            np.testing.assert_allclose(seen[k, [names.index(f"{nm}_mean_{tau}") for nm in now]], mean, atol=1e-5)
            np.testing.assert_allclose(seen[k, [names.index(f"{nm}_meansq_{tau}") for nm in now]], meansq, atol=1e-5)
    batch = EpisodeBatch("MillVib-Valve-v1", 2, config="rolling", **kw)
    out = [batch.reset([120004, 120005])[0]]
    for a in actions:
        out.append(batch.step(np.repeat(a[None], 2, axis=0))[0][0])
    np.testing.assert_array_equal(np.array(out), seen.astype(np.float32))  # the same engine: the same bytes
    for bad in ([16, 4], [1], [2, 100001], "3"):
        with pytest.raises(ValueError, match="history_filters"):
            gym.make("MillVib-Valve-v1", config="rolling", observation={"history_filters": bad})


@pytest.mark.parametrize("argv, what", [
    (["headroom", "--env-version", "v0", "--quiet"], "v1"),
    (["distill", "--iterations", "0", "--save-dir", "d"], "iterations"),
    (["distill", "--episodes", "101", "--save-dir", "d"], "episodes"),
    (["distill", "--range-v", "nan", "--save-dir", "d"], "range_v"),
    (["distill", "--net", "0", "--save-dir", "d"], "net"),
    (["distill", "--history", "4", "2", "--save-dir", "d"], "history_samples"),
    (["distill", "--filters", "1", "--save-dir", "d"], "history_filters"),
    (["distill", "--save-dir", "/proc/version/x"], "--save-dir"),
    (["distill", "--preview", "perfect", "--save-dir", "d"], "--preview"),
])
def test_the_new_commands_refuse_bad_input_in_one_line_before_any_work(argv, what, tmp_path, monkeypatch, capsys):
    from millvib_env.cli import main as cli_main

    monkeypatch.chdir(tmp_path)
    try:
        status = cli_main(argv)
    except SystemExit as exc:
        status = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and what in err[0], err
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_distill_writes_an_agent_that_loads_and_runs_as_any_other(tmp_path, capsys):
    """One DAgger iteration on one training episode: the folder is an ordinary agent (the benchmark's loader runs
    it), its card says how it was made and selected, and it was scored on the validation plants. Beside its
    progress bar, the run says what it does between rollouts: fitting, scoring, and the best cost so far."""
    from millvib_env.training.distill import distill

    card = distill("startup", iterations=1, episodes=1, epochs=1, save_dir=tmp_path / "agent", progress=True,
                   validation_episodes=4)
    err = capsys.readouterr().err
    assert "iteration 1: fitting the student to" in err
    assert "iteration 1: scoring it on validation plants 15000-15003" in err
    assert re.search(r"iteration 1: cost [0-9.e+-]+; best [0-9.e+-]+ \(iteration 1\)", err), err[-400:]
    assert card["selected"]["iteration"] == 1 and card["validation"]["episodes"] == 4
    assert card["validation"]["seeds"] == "15000-15003"  # the first of the task's validation plants
    agent = load_controller(str(tmp_path / "agent"), "startup")
    assert agent.env_id == "MillVib-Valve-v1" and agent.card["trained_by"].startswith("DAgger from mpc-preview")
    assert agent.card["env_kwargs"]["observation"]["preview_gauge"] == "measured"  # learned as the benchmark runs it
    rec = run_episodes(agent, [20000], task="startup")[0]
    assert np.isfinite(rec["cost"]) and not rec["diverged"]


def test_distill_scores_the_students_from_the_iteration_asked_and_fits_in_the_batch_asked(tmp_path, monkeypatch):
    """`distill(validate_from=K, batch=B)`: the students of the iterations before K are fitted and recorded, never
    scored or shipped; the card says where the candidates began and the fit's batch."""
    import millvib_env.training.distill as dist

    scored, sizes = [], []
    score, fit = dist.validation_result, dist._fit

    def spy_score(folder, card=None, episodes=40):
        scored.append(card["trained_by"])
        return score(folder, card, episodes=episodes)

    def spy_fit(model, X, Y, stats, epochs, seed, **how):
        sizes.append(how["batch"])
        return fit(model, X, Y, stats, epochs, seed, **how)
    monkeypatch.setattr(dist, "validation_result", spy_score)
    monkeypatch.setattr(dist, "_fit", spy_fit)
    card = dist.distill("startup", iterations=2, episodes=1, epochs=1, save_dir=tmp_path / "agent", progress=False,
                        validation_episodes=1, validate_from=2, batch=512, net=(8,))
    assert sizes == [512, 512] and len(scored) == 1 and "batch 512" in card["trained_by"]
    assert [("cost_mean" in r) for r in card["iterations"]] == [False, True]
    assert card["selected"]["iteration"] == 2 and "from iteration 2 on" in card["selected"]["how"]
    with pytest.raises(ValueError, match="validate_from = 3 is invalid"):
        dist.distill("startup", iterations=2, validate_from=3, save_dir=tmp_path / "b", progress=False)


def test_a_distilled_student_does_not_depend_on_torchs_thread_count(tmp_path):
    """The same distillation started with torch on two threads and on one gives the same network to the bit: how a
    product is split over threads rounds its sums (the orthogonal initialisation's QR, the fit's products), and the
    number of threads torch starts with is the machine's core count."""
    import torch
    from stable_baselines3 import PPO

    from millvib_env.training.distill import distill

    before = torch.get_num_threads()
    kw = dict(iterations=1, episodes=1, epochs=1, progress=False, validation_episodes=1, net=(256, 256))
    try:
        for n in (2, 1):
            torch.set_num_threads(n)
            distill("startup", save_dir=tmp_path / f"threads-{n}", **kw)
    finally:
        torch.set_num_threads(before)
    a, b = (PPO.load(tmp_path / f"threads-{n}" / "model.zip", device="cpu").policy.state_dict() for n in (2, 1))
    assert [k for k in a if not torch.equal(a[k], b[k])] == []


def test_an_interrupted_distillation_goes_on_from_its_last_finished_iteration_to_the_same_agent(tmp_path, monkeypatch):
    """A distillation cut after its second of three iterations keeps them in its journal (SAVE_DIR.partial) and
    writes no agent; the same call refuses to start over the journal, another run's options cannot resume it, and
    `resume` runs only the third iteration, to the agent an uninterrupted run writes: every weight and statistic the
    same, the card the same but for its name and time. A run cut in its first iteration keeps nothing."""
    import json

    import millvib_env.training.distill as dist
    import millvib_env.training.distill_journal as dj
    from stable_baselines3 import PPO

    from millvib_env.threads import one_torch_thread

    one_torch_thread()  # as the first run's scoring sets it: the critic's initial weights (unused by a student, never
    # fitted) depend on torch's thread count, the actor's do not
    kw = dict(iterations=3, episodes=1, epochs=1, progress=False, validation_episodes=1, net=(8,))
    whole = dist.distill("startup", save_dir=tmp_path / "whole", **kw)
    record, ran = dj.DistillJournal.record, []

    def cut(self, it, *args, **how):
        record(self, it, *args, **how)
        if it == 1:
            raise KeyboardInterrupt
    monkeypatch.setattr(dj.DistillJournal, "record", cut)
    out, journal = tmp_path / "cut", tmp_path / "cut.partial"
    with pytest.raises(KeyboardInterrupt):
        dist.distill("startup", save_dir=out, **kw)
    assert not out.exists() and json.loads((journal / "journal.json").read_text())["done"] == 2
    monkeypatch.setattr(dj.DistillJournal, "record", record)
    with pytest.raises(ValueError, match="holds the finished iterations of an unfinished distillation into"):
        dist.distill("startup", save_dir=out, **kw)
    with pytest.raises(ValueError, match=r"journal of another distillation \(epochs 1 there, 2 here\)"):
        dist.distill("startup", save_dir=out, **{**kw, "epochs": 2}, resume=True)
    iteration = dist._Run.iteration

    def counted(self, it, *args):
        ran.append(it)
        return iteration(self, it, *args)
    monkeypatch.setattr(dist._Run, "iteration", counted)
    card = dist.distill("startup", save_dir=out, resume=True, **kw)
    assert ran == [2] and not journal.exists()
    for c in (card, whole):
        assert c.pop("wall_time_s") >= 0 and c.pop("name") in ("cut", "whole")
    assert card == whole
    a, b = (PPO.load(d / "model.zip", device="cpu").policy.state_dict() for d in (out, tmp_path / "whole"))
    assert all(np.array_equal(a[k].numpy(), b[k].numpy()) for k in a)
    za, zb = (np.load(d / "vecnormalize.npz") for d in (out, tmp_path / "whole"))
    assert all(np.array_equal(za[k], zb[k]) for k in za.files)

    def first(self, it, *args):  # cut inside the first iteration: nothing is kept, so nothing is left
        raise KeyboardInterrupt
    monkeypatch.setattr(dist._Run, "iteration", first)
    with pytest.raises(KeyboardInterrupt):
        dist.distill("startup", save_dir=tmp_path / "early", **kw)
    assert not (tmp_path / "early.partial").exists() and not (tmp_path / "early").exists()
    with pytest.raises(ValueError, match="there is no journal"):
        dist.distill("startup", save_dir=tmp_path / "early", resume=True, **kw)


@pytest.mark.slow
def test_distill_on_the_classical_preview_controller_learns_what_it_misses_from_its_command(tmp_path, monkeypatch):
    """`distill --on pid-pf-preview`: the student's environment runs pid-pf-preview's feedforward (its card holds the
    numbers), and each label is what the teacher adds to the PID's and the feedforward's command, from the same
    sample, within +-range_v."""
    import millvib_env.training.distill as dist

    seen = {}
    fit = dist._fit

    def spy(model, X, Y, stats, epochs, seed, **how):
        seen["Y"] = Y
        return fit(model, X, Y, stats, epochs, seed, **how)
    monkeypatch.setattr(dist, "_fit", spy)
    card = dist.distill("startup", iterations=1, episodes=1, epochs=1, save_dir=tmp_path / "agent", progress=False,
                        validation_episodes=1, on="pid-pf-preview", range_v=10.0)
    ff = load_controller("pid-pf-preview", "startup", version="v1")
    assert card["on"] == "pid-pf-preview" and card["name"] == "agent"
    assert card["env_kwargs"]["actions"]["residual_feedforward"] == ff.feedforward_gains()
    assert card["env_kwargs"]["actions"]["residual_range_v"] == 10.0
    assert np.all(np.abs(seen["Y"]) <= 1.0) and np.any(np.abs(seen["Y"]) < 1.0)
    with pytest.raises(ValueError, match="on = 'pid-pf-robust' is invalid"):
        dist.distill("startup", iterations=1, episodes=1, save_dir=tmp_path / "b", progress=False, on="pid-pf-robust")


def test_the_iteration_budget_draws_one_iterations_worth_per_epoch_and_every_pooled_sample_before_any_again():
    """`distill(budget="iteration")`'s fit (`_fit` with per_epoch): an epoch is per_epoch samples in batches of at most
    1024, and the draws run through whole shuffles of the pool, so no sample comes twice before each came once (a
    shuffle's last batch is short rather than reach into the next).
    Without per_epoch, an epoch is one pass over the pool (the `pool` budget)."""
    import types

    import torch

    from millvib_env.catalog.normalization import ObsStats
    from millvib_env.training.distill import _fit

    seen = []

    class Net(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.lin = torch.nn.Linear(1, 1)

        def forward(self, x):
            seen.append(x[:, 0].round().long().tolist())
            return self.lin(x)
    n = 2500
    X = np.arange(n, dtype=np.float32)[:, None]
    stats = ObsStats(np.zeros(1), np.ones(1), 1.0, 1e9, 0.0)  # normalisation that leaves the sample's index readable
    policy = types.SimpleNamespace(mlp_extractor=types.SimpleNamespace(policy_net=Net()),
                                   action_net=torch.nn.Identity())
    model = types.SimpleNamespace(policy=policy)
    _fit(model, X, np.zeros((n, 1), np.float32), stats, epochs=3, seed=0, per_epoch=1500)
    batches = seen[:-1]  # the last call scores the whole pool
    assert [len(b) for b in batches] == [1024, 476, 1000, 500, 1024, 476]  # 1500 an epoch; a shuffle ends at 2500
    drawn = [i for b in batches for i in b]
    assert sorted(drawn[:n]) == list(range(n)) and sorted(drawn[n:]) == sorted(set(drawn[n:]))
    seen.clear()
    _fit(model, X, np.zeros((n, 1), np.float32), stats, epochs=2, seed=0)
    assert [len(b) for b in seen[:-1]] == [1024, 1024, 452] * 2


def test_a_large_batch_is_normalised_as_each_row_alone():
    """`ObsStats.normalize` transforms a large batch (a distillation's pool) a block of rows at a time: every element
    goes through the same IEEE operations (subtract, divide by a correctly rounded square root, clip, round to
    float32), so the numbers are the row's own exactly, on any machine."""
    from millvib_env.catalog.normalization import _ROWS, ObsStats

    rng = np.random.default_rng(3)
    stats = ObsStats(rng.normal(size=5), rng.random(5) * 4.0, 10.0, 2.0, 1e-8)
    X = (rng.normal(size=(2 * _ROWS + 7, 5)) * 3.0).astype(np.float32)
    Z = stats.normalize(X)
    assert Z.dtype == np.float32 and Z.shape == X.shape
    for i in (0, _ROWS - 1, _ROWS, 2 * _ROWS + 6):
        assert np.array_equal(Z[i], stats.normalize(X[i]))
    assert np.abs(Z).max() <= 2.0


def test_a_new_episode_starts_the_oracle_afresh():
    """In a plain loop, the second episode of one controller equals a fresh controller's on the same seed: no
    model, integral or residual of the first plant is carried over."""
    ctrl = load_controller("mpc-oracle", "varied", version="v1")
    env = ctrl.make_env(**SHORT)
    _plain_episode(ctrl, env, 320001)
    second = _plain_episode(ctrl, env, 320002)
    fresh = load_controller("mpc-oracle", "varied", version="v1")
    assert _plain_episode(fresh, fresh.make_env(**SHORT), 320002) == second


@pytest.mark.parametrize("task", ["startup", "change"])
def test_the_commands_of_a_batch_are_each_environments_own(task):
    """`teacher_commands` computes every environment's linear term on the stacked models at once; each command
    must be the one that environment alone gets (`teacher_command(i)`, one slot), through model rebuilds (the
    start's ramp, the plant change) and a restarted episode. Both paths make the same arithmetic; 1e-9 V is far
    below any command's resolution and far above rounding, and a wrong slot or a stale estimate is volts off."""
    from millvib_env.envs.batch import EpisodeBatch

    seeds = [1500, 1501, 1502]
    pair = []
    for _ in range(2):
        ctrl = load_controller("mpc-preview", task, version="v1")
        venv = EpisodeBatch(ctrl.env_id, len(seeds), config=get_task(task).config, episode_s=0.1)
        venv.reset(seeds)
        ctrl.attach(venv.core)
        ctrl.on_reset(venv.reset_infos, range(len(seeds)))
        pair.append((ctrl, venv))
    (batch, vb), (alone, va) = pair
    for _ in range(vb.core.settings.max_steps + 5):  # past the end: the restarted episodes too
        u = batch.teacher_commands()
        u_alone = np.array([alone.teacher_command(i) for i in range(len(seeds))])
        np.testing.assert_allclose(u, u_alone, rtol=0.0, atol=1e-9)
        for ctrl, venv in pair:
            _, dones, _ = venv.step((u / venv.core.settings.u_range)[:, None].astype(np.float32))
            if dones.any():
                ctrl.on_reset(venv.reset_infos, np.flatnonzero(dones))
    assert batch.solves == alone.solves > 0


def test_the_offset_free_estimate_removes_a_steady_model_error_whole():
    """The prediction already holds the estimate w, so what it misses is r - w for a steady model error r: the
    estimate must settle at r (zero miss), not at r / 2 as a filter of the miss itself does."""
    from millvib_env.control.mpc import offset_free_update

    r = np.array([2.0e-7, -3.0e-4, 5.0e3, 0.0])
    w = None
    for _ in range(400):
        w = offset_free_update(w, r - (0.0 if w is None else w), 0.1)
    np.testing.assert_allclose(w, r, rtol=1e-6)


def test_the_bounds_qp_solve_is_the_exact_box_constrained_minimum_and_a_failed_one_is_no_answer():
    """`mpc._solve_first_move` (DAQP on the condensed QP): on random box-constrained QPs, some moves at the bounds,
    its first move is the minimum that an independent method finds (the same QP as bounded least squares,
    scipy's `lsq_linear`, to 1e-9); a solve that DAQP reports failed (a negative exit flag) gives no move (nan)."""
    import types

    import daqp
    from scipy.optimize import lsq_linear

    from millvib_env.control.mpc import _solve_first_move

    rng = np.random.default_rng(5)
    for _ in range(5):
        M = rng.standard_normal((6, 6))
        H = M @ M.T + 0.1 * np.eye(6)
        solver = daqp.Model()
        solver.setup(H, np.zeros(6), np.zeros((0, 6)), np.full(6, 1.0), np.full(6, -1.0))
        q = rng.standard_normal(6) * 3.0
        z0, flag = _solve_first_move(solver, q)
        L = np.linalg.cholesky(H)  # 0.5 z'Hz + q'z = 0.5 |L'z + L^-1 q|^2 + const
        ref = lsq_linear(L.T, -np.linalg.solve(L, q), bounds=(-1.0, 1.0), method="bvls", tol=1e-14).x
        assert flag == 1 and abs(z0 - ref[0]) < 1e-9, (z0, ref[0])
    failed = types.SimpleNamespace(update=lambda f: None, solve=lambda: (np.zeros(6), 0.0, -4, {}))
    z0, flag = _solve_first_move(failed, np.zeros(6))
    assert np.isnan(z0) and flag == -4


def test_what_the_preview_bound_knows_ahead_can_be_withdrawn_course_by_course():
    """`MPCSettings.ahead` (scripts/bound_knowledge.py): a course left out is held at its value now over the whole
    horizon, exactly as the oracle (no preview) holds it, and the courses kept are the full preview's own; the force
    steps from the gauge need a measured preview and differ from the plant's where the gauge errs."""
    from dataclasses import replace

    from millvib_env.envs.batch import EpisodeBatch

    seeds = [120001, 120002]
    base = load_controller("mpc-preview", "change", version="v1").settings
    venv = EpisodeBatch("MillVib-Valve-v1", len(seeds), config="change", episode_s=0.1,
                        observation={"preview_samples": [1, 2, 4, 8, 16, 24, 32, 40], "preview_gauge": "measured"})
    venv.reset(seeds)
    idx = np.arange(len(seeds))
    xd0 = np.zeros(len(seeds))
    for _ in range(40):  # into the episode: the ripple and eccentricity move, a course has samples behind it
        venv.step(np.zeros((len(seeds), 1), dtype=np.float32))

    def exo(**kw) -> np.ndarray:
        ctrl = MPCPolicy("mpc-preview", replace(base, **kw))
        ctrl.attach(venv.core)
        return ctrl._exogenous(idx, xd0, base.horizon)

    full, oracle = exo(), exo(preview=False)
    np.testing.assert_array_equal(exo(ahead=()), oracle)
    for k, course in enumerate(("ripple", "setpoint")):  # columns 1 and 2
        cut = exo(ahead=tuple(a for a in base.ahead if a != course))
        np.testing.assert_array_equal(cut[:, :, 1 + k], oracle[:, :, 1 + k])
        np.testing.assert_array_equal(cut[:, :, 2 - k], full[:, :, 2 - k])
        np.testing.assert_array_equal(cut[:, :, 0], full[:, :, 0])
    assert np.ptp(full[:, :, 1], axis=1).min() > 0.0  # the ripple does move over the horizon
    no_force = exo(ahead=("setpoint", "ripple"))
    np.testing.assert_array_equal(no_force[:, :, 0], oracle[:, :, 0])
    gauge = exo(force_steps="gauge")
    np.testing.assert_array_equal(gauge[:, :, 1:], full[:, :, 1:])
    assert not np.array_equal(gauge[:, :, 0], full[:, :, 0])
    exact = EpisodeBatch("MillVib-Valve-v1", 1, config="change", episode_s=0.1)
    exact.reset(seeds[:1])
    ctrl = MPCPolicy("mpc-preview", replace(base, force_steps="gauge"))
    ctrl.attach(exact.core)
    with pytest.raises(ValueError, match="preview_gauge"):
        ctrl._exogenous(np.arange(1), np.zeros(1), base.horizon)


@pytest.mark.parametrize("kw, what", [({"ahead": ("force",)}, "MPCSettings.ahead"),
                                      ({"ahead": "ripple"}, "MPCSettings.ahead"),
                                      ({"ahead": ("ripple", "ripple")}, "MPCSettings.ahead"),
                                      ({"force_steps": "exact"}, "MPCSettings.force_steps"),
                                      ({"tail": "dare"}, "MPCSettings.tail")])
def test_what_the_bound_knows_ahead_refuses_a_name_it_does_not_know(kw, what):
    with pytest.raises(ValueError, match=re.escape(what)):
        MPCSettings(**kw)


def test_the_distillation_pool_grows_in_place_and_keeps_numpys_statistics():
    """`distill._Pool` keeps every iteration's samples in order, grows past the rows it foresaw, and gives the
    statistics of numpy's mean and var of the pooled float32 samples (a block at a time, the running sum carried
    as a row: the same sums, compared here within float32 rounding of a sum of that many rows) and the pool
    normalised into its own buffer, as `ObsStats.normalize` gives it."""
    from millvib_env.training.distill import _Pool

    rng = np.random.default_rng(5)
    parts = [((rng.normal(size=(n, 4)) * [1.0, 30.0, 1e-3, 5.0]) + [0.0, 1e3, 2.0, -7.0]).astype(np.float32)
             for n in (70000, 70000, 90000)]
    pool = _Pool(2 * 70000)  # the third part is longer than foreseen: the buffers grow
    for X in parts:
        pool.add(X, X[:, :1] * 2.0)
    X = np.concatenate(parts)
    assert pool.n == len(X) and np.array_equal(pool.X[:pool.n], X) and np.array_equal(pool.Y[:pool.n], 2.0 * X[:, :1])
    stats = pool.stats()
    np.testing.assert_allclose(stats.mean, X.mean(0), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(stats.var, X.var(0), rtol=1e-4)
    Xn, Yn = pool.normalized(stats)
    assert np.array_equal(Xn, stats.normalize(X)) and np.array_equal(Yn, pool.Y[:pool.n])
    with pytest.raises(ValueError, match="out is invalid"):
        stats.normalize(X, out=np.empty((3, 4), np.float32))
