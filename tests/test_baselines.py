"""The stronger baselines: the plant's linearisation as API, the LQR reference, the adaptive PID."""
import numpy as np
import pytest

from millvib_env import MillParams
from millvib_env.analysis.linear import linearize
from millvib_env.control.lqr import LQRWeights, lqr_design
from millvib_env.catalog.agents import agent_base, agent_validation_cost, list_agents
from millvib_env.catalog.factory import control_entry, load_controller
from millvib_env.plant.kernel import rhs_vector
from millvib_env.plant.model import IPL, IV, IX, drive_vector, pack
from millvib_env.params import PIDGains
from millvib_env.tasks import get_task, list_tasks
from millvib_env.evaluation.evaluate import run_episodes
from tests._source import parsed


@pytest.mark.parametrize("friction", ["stick", "sliding"])
def test_linearisation_predicts_the_plants_response_to_a_small_input(friction):
    params = MillParams(c1=5e5, Ct=1e-10, pulse_amp=0.0)
    ss = linearize(params, friction=friction)
    assert ss.A.shape == (3, 3) and ss.B.shape == (3, 1) and ss.C.shape == (3, 3) and ss.D.shape == (3, 1)
    # the pressure rate of a small valve opening, from the full right-hand side and from B
    du = 0.01
    c = drive_vector(PIDGains(0.0), u_ext=ss.u0 + du, pid_on=False)
    dy = rhs_vector(0.0, ss.op.y, pack(params), c)
    assert dy[IPL] == pytest.approx(ss.B[2, 0] * du, rel=1e-3)
    assert abs(dy[IX]) < 1e-12 and abs(dy[IV]) < 1e-6


def test_linearisation_converts_to_python_control():
    control = pytest.importorskip("control")
    sys = linearize(MillParams()).to_control()
    assert isinstance(sys, control.StateSpace) and sys.nstates == 3


@pytest.mark.parametrize("task", list_tasks())
def test_lqr_closed_loop_is_stable_on_every_plant_of_the_oracle_grid(task):
    weights = LQRWeights(**control_entry(get_task(task), "lqr-oracle")["weights"])
    grid = control_entry(get_task(task), "pid-oracle")
    lqr = load_controller("lqr-oracle", task)
    for c1 in grid["c1_grid"]:
        for ct in grid["ct_grid"]:
            K, A_cl, A, B = lqr_design(MillParams(c1=c1, Ct=ct), weights)
            assert np.linalg.eigvals(A_cl).real.max() < 0, (c1, ct)
            # and with the gains as the environment applies them (clipped to its action bounds)
            g = np.clip(np.array([K[0], -K[3], K[1], K[2]]), lqr.gain_map.lo, lqr.gain_map.hi)
            K_env = np.array([g[0], g[2], g[3], -g[1]])
            assert np.linalg.eigvals(A - B @ K_env[None, :]).real.max() < 0, (c1, ct)


def test_the_v1_lqr_oracle_designs_for_every_named_scenarios_plant_even_one_beyond_the_amplifier():
    """The high-leakage scenario's plant (Ct = 5e-9) takes about 180 V to hold against its leak, beyond v1's
    +-10 V amplifier: linearised with that limit the command had no effect (B = 0) and the discrete Riccati
    equation had no solution, so `millvib headroom --task startup` failed. The design model leaves the
    actuator's limits out, as it leaves out the spool's stroke; a plant within them gets the gains it had."""
    from millvib_env.envs.scenarios import get_scenario, list_scenarios

    lqr = load_controller("lqr-oracle", "startup", version="v1")
    for name in list_scenarios():
        params = get_scenario(name).params
        gains = lqr.gains_for(params.get("c1", MillParams().c1), params.get("Ct", MillParams().Ct))
        assert np.all(np.isfinite(gains)), name
    held = lqr.base_params.replace(Ct=5e-9)
    assert linearize(held.replace(valve_wn_hz=0.0, xv_max=np.inf), 0.0, friction="stick").B[2, 0] == 0.0  # the cause
    within = lqr.base_params.replace(c1=1.25e5, valve_wn_hz=0.0, xv_max=np.inf)  # held well within +-10 V
    assert within.u_max == 10.0
    limited, free = (linearize(within.replace(u_max=u), 0.0, friction="stick") for u in (10.0, np.inf))
    np.testing.assert_array_equal(limited.A, free.A)  # so its design is the one it had
    np.testing.assert_array_equal(limited.B, free.B)


def test_lqr_oracle_runs_in_the_benchmark_loop_with_pressure_feedback():
    lqr = load_controller("lqr-oracle", "rolling")
    assert lqr.gain_map.dim == 4
    recs = run_episodes(lqr, [120_000, 120_001], task="rolling")
    assert all(np.isfinite(r["cost"]) and not r["diverged"] for r in recs)


@pytest.mark.parametrize("version", ["v0", "v1"])
@pytest.mark.parametrize("c1, ct", [(2.25e6, 5e-16), (5e5, 1e-10), (1.25e5, 5e-9)])
def test_adaptive_estimates_converge_on_a_fixed_plant_under_excitation(c1, ct, version):
    # steady rolling: eccentricity, force steps and gauge corrections excite the loop. The damping
    # estimate carries the observer's small bristle error and the 10 Hz high-pass's edge: measured
    # within 0.5-7 % over these plants and seeds, so 15 % is asserted at the episode's end; the
    # leakage estimate is within 2 % wherever the leak is observable (Ct >= 1e-11). On v1 the valve
    # flow follows the spool, which the estimator observes (within 0.3 % for Ct >= 1e-12, measured;
    # before the spool observer, the flow read 0 there and Ct fell to its 1e-17 bound)
    ctrl = load_controller("pid-adaptive", "rolling", version=version)
    fixed = {"randomize": {"c1": {"dist": "fixed", "low": c1}, "Ct": {"dist": "fixed", "low": ct}}}
    finals = []

    class Spy(type(ctrl)):
        def on_step(self, infos):
            super().on_step(infos)
            finals.append((self.estimator.c1_hat.copy(), self.estimator.ct_hat.copy()))

    ctrl.__class__ = Spy
    recs = run_episodes(ctrl, [110_000, 110_001, 110_002], task="rolling", env_kwargs=fixed)
    c1_hat, ct_hat = finals[-1]
    np.testing.assert_allclose(c1_hat, c1, rtol=0.15)
    if ct >= 1e-11:
        np.testing.assert_allclose(ct_hat, ct, rtol=0.02)
    assert all(r["c1_log_error"] < 0.1 for r in recs)  # and on average over each episode


def test_the_adaptive_estimators_spool_observer_follows_the_plants_spool():
    """v1's valve lags its command: the estimator's spool (plant_rhs's own spool equations, exactly discretised,
    along the recorded command) against the plant's spool state at every sample of an episode. Measured: 6e-6 of
    the spool's RMS stroke; held to 1e-3 (a command read one sample late, or the trapezoidal rule, err by 1e-2)."""
    from millvib_env.control.adaptive import model_acceleration
    from millvib_env.evaluation.evaluate import EpisodeBatch, env_kwargs_for
    from millvib_env.plant.model import IXS

    ctrl = load_controller("pid-adaptive", "rolling", version="v1")
    est = ctrl.estimator
    assert est.spool_model[:, 2].any()  # v1 has a valve with dynamics
    venv = EpisodeBatch(ctrl.env_id, 1, **env_kwargs_for(ctrl, "rolling", None))
    venv.core.record_signals = True
    obs = venv.reset([110_000])
    ctrl.on_reset(venv.reset_infos, [0])
    spool, prev, errors, strokes = np.zeros(2), None, [], []
    for _ in range(40):
        obs, _, infos = venv.step(ctrl.predict(obs, deterministic=True)[0], restart=False)
        ctrl.on_step(infos)
        sig = infos[0]["signals"]
        for k in range(sig["x"].size):  # from the previous sample to this one: the observer's spool at each
            cols = [np.array([sig[name][k]]) if prev is None else np.array([prev[j], sig[name][k]])
                    for j, name in enumerate(("t", "x", "v", "pL", "u"))]
            model_acceleration(*cols, 0.0, est.p_model, np.empty(len(cols[0])), np.empty(len(cols[0])),
                               est.spool_model, spool, prev is None)
            prev = [sig[name][k] for name in ("t", "x", "v", "pL", "u")]
            errors.append(spool[0] - venv.core.YS[0, 1 + k, IXS])
            strokes.append(venv.core.YS[0, 1 + k, IXS])
    rms = np.sqrt(np.mean(np.square(strokes)))
    assert rms > 1e-5  # the spool moved
    assert np.sqrt(np.mean(np.square(errors))) < 1e-3 * rms
    assert not load_controller("pid-adaptive", "rolling", version="v0").estimator.spool_model[:, 2:].any()


def test_adaptive_gives_the_fallback_until_it_has_seen_motion():
    ctrl = load_controller("pid-adaptive", "rolling", version="v0")
    quiet = {"disturbances": {"setpoint_steps": None, "force_steps": None, "eccentricity": None,
                              "sensor_noise": None}, "plant": {"pulse_amp": 0.0}}
    recs = run_episodes(ctrl, [110_000], task="rolling", env_kwargs=quiet)
    assert np.isnan(ctrl.estimator.c1_hat[0])  # the episode's last estimate: no episode starts after it
    assert np.isnan(recs[0]["c1_log_error"])  # never estimated: nothing moved
    np.testing.assert_allclose(ctrl._actions[0], ctrl.gain_map.action(ctrl.fallback), atol=1e-6)


def test_the_adaptive_pids_gains_for_every_environment_at_once_are_each_plants_own():
    """`gains_at` reads the gain table once for all the environments' estimates (unknown c1: the fallback,
    unknown Ct: the nominal one). Each row is `gains_for` of that plant: the same operations, elementwise; the
    tolerance allows a transcendental's last bit, which a vectorised and a scalar path may round apart."""
    ctrl = load_controller("pid-adaptive", "rolling")
    rng = np.random.default_rng(3)
    c1, ct = 10.0 ** rng.uniform(4.5, 7.0, 50), 10.0 ** rng.uniform(-17.0, -8.0, 50)
    c1[:5] = ctrl.table.c1_grid[:5]  # on the grid's lines
    ct[5:10] = ctrl.table.ct_grid[-5:]
    c1[10:13], ct[13:16] = np.nan, np.nan
    batched = ctrl.gains_at(c1, ct)
    one = np.array([ctrl.gains_for(a, b) for a, b in zip(c1, ct)])
    np.testing.assert_allclose(batched, one, rtol=1e-13, atol=0.0)
    np.testing.assert_array_equal(batched[10:13], np.broadcast_to(ctrl.fallback, (3, 3)))


def test_the_adaptive_estimator_runs_at_the_envs_sample_rate_or_refuses():
    import gymnasium as gym

    from millvib_env.catalog.factory import load_controller
    from millvib_env.envs.config import load_env_config

    cfg = load_env_config("rolling", sample_rate_hz=20000)
    ctrl = load_controller("pid-adaptive", task="rolling", config=cfg)
    assert ctrl.estimator.fs == 20000
    env = ctrl.make_env(sample_rate_hz=20000)
    obs, _ = env.reset(seed=120000)
    for _ in range(3):
        obs, *_ = env.step(ctrl.predict(obs)[0])
    wrong = load_controller("pid-adaptive", task="rolling")  # 10 kHz, in a 20 kHz env: refused, not biased
    env = gym.make("MillVib-GainSchedule-v0", config="rolling", sample_rate_hz=20000)
    loop = type(ctrl.make_env())(env, wrong)
    obs, _ = loop.reset(seed=120000)
    with pytest.raises(ValueError, match="sampled at 20000 Hz"):
        loop.step(wrong.predict(obs)[0])


def test_the_controller_groups_expand_to_their_members_once():
    from millvib_env.evaluation.benchmark.lineup import DEPLOYABLE_CLASSICAL, _expand_groups
    from millvib_env.tasks import get_task

    start, rolling = get_task("startup"), get_task("rolling")
    assert _expand_groups(["classical", "pid-paper"], "v1", start) == list(DEPLOYABLE_CLASSICAL)
    assert _expand_groups(["bounds"], "v1", start) == ["pid-pf-oracle", "lqr-oracle", "mpc-oracle", "mpc-preview"]
    assert _expand_groups(["bounds"], "v0", start) == ["pid-pf-oracle", "lqr-oracle"]  # no MPC on the analog loop
    assert _expand_groups(["my-agent", "classical"], "v1", start)[0] == "my-agent"
    # the mission's question: the fixed PID, the reference, the preview's classical controller, the learned controller
    # on it with the lowest validation cost, the bound
    on_it = [a for a in list_agents(rolling, "v1", retired=False) if agent_base(a) == "pid-pf-preview"]
    assert len(on_it) >= 2  # the students and what was trained from them
    answer = _expand_groups(["answer"], "v1", rolling)
    assert answer[:3] == ["pid-paper", "pid-pf-robust", "pid-pf-preview"] and answer[4:] == ["mpc-preview"]
    assert answer[3] in on_it and agent_validation_cost(answer[3]) == min(map(agent_validation_cost, on_it))
    assert _expand_groups(["on-preview"], "v1", rolling) == on_it  # every learned row of the preview set
    with pytest.raises(ValueError, match="'on-preview' is empty for task rolling in v0"):
        _expand_groups(["on-preview"], "v0", rolling)  # the analog loop has no preview controller to learn on
    assert _expand_groups(["answer"], "v0", rolling) == ["pid-paper", "pid-pf-robust"]


def test_a_new_fixed_gain_baseline_is_one_registry_entry_and_its_config_entry(tmp_path, monkeypatch):
    """docs/maintainers.md's recipe: a registry entry (`catalog.registry.Baseline.fixed`) and the gains in the task's
    control config are all a new fixed-gain baseline needs to load and run by name, and to be named as gains."""
    import shutil

    from millvib_env._paths import config_dir
    from millvib_env.catalog import registry

    root = tmp_path / "configs"
    shutil.copytree(config_dir(), root)
    path = root / "control" / "v1" / "startup.yaml"
    path.write_text(path.read_text() + "pid-mine:\n  gains: [2.0e5, 1.0e6, 100.0, 1.0e-4]\n  how: a test entry\n")
    monkeypatch.setenv("MILLVIB_CONFIGS", str(root))
    monkeypatch.setitem(registry.REGISTRY, "pid-mine", registry.Baseline.fixed("a test baseline"))
    ctrl = load_controller("pid-mine", "startup", version="v1")
    assert ctrl.gains.tolist() == [2.0e5, 1.0e6, 100.0, 1.0e-4] and ctrl.description == "a test entry"
    assert ctrl.env_id == "MillVib-GainSchedule-v1"
    recs = run_episodes(ctrl, [20_000])
    assert np.isfinite(recs[0]["cost"])
    from millvib_env.catalog.named import resolve_named_gains

    assert resolve_named_gains({"actions": {"residual_gains": "pid-mine"}}, "startup", "v1")["actions"] == {
        "residual_gains": [2.0e5, 1.0e6, 100.0, 1.0e-4]}


def test_the_env_layer_never_reads_the_control_configs(tmp_path, monkeypatch):
    """envs/ imports nothing of the control layer, the training layer or the tasks (a `Task` carries its env config,
    so tasks.py stands above envs/), and runs with configs/control/ gone: the tuned gains reach it as numbers,
    resolved above it (catalog.named)."""
    import ast
    import shutil
    from pathlib import Path

    import millvib_env.envs as envs_pkg
    from millvib_env._paths import config_dir
    from millvib_env.envs.batch import EpisodeBatch

    for path in Path(envs_pkg.__file__).parent.glob("*.py"):
        for node in ast.walk(parsed(path)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not [n for n in names if n.startswith(("millvib_env.control", "millvib_env.training",
                                                          "millvib_env.tasks"))], path
    root = tmp_path / "configs"
    shutil.copytree(config_dir(), root)
    shutil.rmtree(root / "control")
    monkeypatch.setenv("MILLVIB_CONFIGS", str(root))
    for env_id in ("MillVib-GainSchedule-v1", "MillVib-Valve-v1"):
        batch = EpisodeBatch(env_id, 2, config="rolling", residual=True,
                             actions={"residual_gains": [1e6, 1e8, 300.0, 1e-8]})
        batch.reset([0, 1])
        obs = batch.step(np.zeros((2, batch.core.settings.act_dim)))[0]
        assert np.all(np.isfinite(obs))


def _numpy_estimator_period(est, state, sig):
    """`PlantEstimator.update` written with numpy and scipy calls (as it was before it was compiled): the reference
    the compiled period is held against. `state`: this environment's sums and filter states, updated, and
    `scale`: the same forgotten sums over the summands' magnitudes, which bound how far another order of
    summation can move each sum."""
    from scipy import signal as ssig

    from millvib_env.control.adaptive import model_acceleration

    p, dt = est.params, 1.0 / est.fs
    m = sig["x"].size
    decay = np.exp(-m * dt / est.settings.tau_s)
    cols = [sig[k] for k in ("t", "x", "v", "pL", "u")]
    if state["last"] is not None:
        cols = [np.concatenate([[prev], col]) for prev, col in zip(state["last"], cols)]
    a_model, ql = np.empty(cols[0].size), np.empty(cols[0].size)
    state["z"] = model_acceleration(*cols, state["z"], est.p_model, a_model, ql, est.spool_model, state["spool"],
                                    state["last"] is None)
    a_model, ql = a_model[-m:], ql[-m:]
    state["last"] = tuple(col[-1] for col in cols)
    net, comp, lk = ql - p.Ap * sig["v"], p.Ap * (p.L1 + sig["x"]) / p.beta_e, sig["pL"] - p.pb
    pl = sig["pL"]
    if state["prev"] is not None:
        net, comp, lk, pl = (np.concatenate([[a], b]) for a, b in zip(state["prev"], (net, comp, lk, pl)))
    terms = 0.5 * (net[1:] + net[:-1]) * dt - 0.5 * (comp[1:] + comp[:-1]) * np.diff(pl)
    lhs, lhs_abs = np.sum(terms), np.sum(np.abs(terms))
    rhs = np.sum(0.5 * (lk[1:] + lk[:-1]) * dt)
    rhs_abs = np.sum(np.abs(0.5 * (lk[1:] + lk[:-1]) * dt))
    state["ct"] = (decay * state["ct"][0] + lhs * rhs, decay * state["ct"][1] + rhs * rhs)
    state["scale"][:2] = decay * state["scale"][:2] + np.array([lhs_abs * rhs_abs, rhs_abs * rhs_abs])
    state["prev"] = (net[-1], comp[-1], lk[-1], pl[-1])
    force = p.mt * (a_model - sig["a"]) - (sig["FL"] - p.FL)
    phi, state["zi"][0] = ssig.sosfilt(est.sos, sig["v"] / est.V_SCALE, zi=state["zi"][0])
    rhs_f, state["zi"][1] = ssig.sosfilt(est.sos, force, zi=state["zi"][1])
    state["R"] = (decay * state["R"][0] + phi @ phi, decay * state["R"][1] + phi @ rhs_f)
    state["scale"][2:4] = decay * state["scale"][2:4] + np.array([phi @ phi, np.abs(phi) @ np.abs(rhs_f)])


def test_the_compiled_adaptive_estimator_is_its_numpy_and_scipy_arithmetic():
    # the compiled period (`adaptive._estimate_period`) repeats the numpy and scipy calls operation for operation;
    # held here against them on an episode's recorded signals (4 environments, from the first period on). numpy's
    # sums and BLAS's dot products choose their order of summation by processor (SIMD width, kernel), and a sum
    # of n terms in another order moves by at most about n * 2.2e-16 of the sum of the terms' magnitudes: where the
    # terms cancel (the leakage regression's numerator), that is far more than the result's own last digits. So
    # each sum is held to 1e-12 of its summands' magnitudes (n is at most a few hundred here: 20x margin or more)
    ctrl = load_controller("pid-adaptive", "rolling")
    est = ctrl.estimator
    periods = []

    class Recorder(type(ctrl)):
        def on_step(self, infos):
            periods.append([{k: np.array(v) for k, v in info["signals"].items()} for info in infos])
            super().on_step(infos)

    ctrl.__class__ = Recorder
    run_episodes(ctrl, [110_000, 110_001, 110_002, 110_003], task="rolling")
    n_env = len(periods[0])
    est.reset_all(n_env)
    states = [{"last": None, "prev": None, "z": 0.0, "spool": np.zeros(2), "ct": (0.0, 0.0), "R": (0.0, 0.0),
               "zi": np.zeros((2, est.sos.shape[0], 2)), "scale": np.zeros(4)} for _ in range(n_env)]
    for sigs in periods[:200]:
        for i, sig in enumerate(sigs):
            est.update(i, sig)
            _numpy_estimator_period(est, states[i], sig)
            want = np.array([*states[i]["ct"], *states[i]["R"], states[i]["z"]])
            bound = 1e-12 * np.maximum(np.abs(want), [*states[i]["scale"], abs(states[i]["z"])])
            assert np.all(np.abs(np.array([*est.acc[i], est.z[i]]) - want) <= bound), (i, est.acc[i], want)
    assert all(np.isfinite(est.c1_hat)) and all(np.isfinite(est.ct_hat))  # the episode moved the plant


def test_the_benchmarks_roles_are_fields_of_the_registry_entries_and_consistent():
    """What the benchmark does with a baseline (the reference, the group 'classical', the paired columns, worker
    processes for a QP every sample) is declared on its registry entry; the tables are read from there. A deployable
    classical controller reads no oracle's information, the reference is one of them and the only one, and a slow
    baseline commands the valve of the sampled loop."""
    from millvib_env.catalog.registry import REFERENCE, REGISTRY
    from millvib_env.evaluation.benchmark import COMPARED_WITH, DEPLOYABLE_CLASSICAL, ROOM_BOUNDS, SLOW_BASELINES

    assert [n for n, b in REGISTRY.items() if b.reference] == [REFERENCE]
    assert REFERENCE in DEPLOYABLE_CLASSICAL
    assert DEPLOYABLE_CLASSICAL == tuple(n for n, b in REGISTRY.items() if b.classical)
    for name in DEPLOYABLE_CLASSICAL:
        atoms = set(REGISTRY[name].information.split("+"))
        assert not atoms & {"params", "state", "pump"}, name
    assert set(COMPARED_WITH) == {n for n, b in REGISTRY.items() if b.compared_with} and COMPARED_WITH
    assert SLOW_BASELINES and all(REGISTRY[n].env_mode == "valve" and REGISTRY[n].loop_only for n in SLOW_BASELINES)
    # the room's bounds know the plant (none is deployable), in the order of their fields, the result's order
    assert list(ROOM_BOUNDS) == ["pid-pf-oracle", "lqr-oracle", "mpc-oracle", "mpc-preview"]
    assert all(REGISTRY[n].bound == what and "params" in REGISTRY[n].information.split("+")
               for n, what in ROOM_BOUNDS.items())
    assert not set(ROOM_BOUNDS) & set(DEPLOYABLE_CLASSICAL)
