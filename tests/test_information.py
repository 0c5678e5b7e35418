"""Same information, same footing: the preview as a gauge measures it, information sets, the classical preview
controller and the verdict against the classical controller of a controller's own information."""
import copy

import numpy as np
import pytest

from millvib_env.catalog.factory import load_controller
from millvib_env.catalog.information import (ATOMS, bound_candidates, classical_candidates, from_env_kwargs,
                                             is_oracle, label)
from millvib_env.catalog.named import resolve_named_gains_for
from millvib_env.control.preview import FF_CHANNELS, PreviewFeedforward, preview_env_kwargs
from millvib_env.catalog.registry import REGISTRY
from millvib_env.envs.batch import EpisodeBatch
from millvib_env.envs.gauge import GaugeSettings, gauge_force, gauge_settings
from millvib_env.envs.observation import OBS_SCALES, slog, unslog
from millvib_env.evaluation.benchmark import run_benchmark
from millvib_env.evaluation.verdict import information_verdict
from millvib_env.tasks import get_task

ROLLING = get_task("rolling")


def _batch(gauge, n=2):
    kw = preview_env_kwargs(gauge=gauge)
    return EpisodeBatch("MillVib-Valve-v1", n, **resolve_named_gains_for({"config": "rolling", **kw}, ROLLING, "v1"))


def _run_zero(b, seeds, steps=400):
    """The first `steps` observations of a zero-action run."""
    obs = [b.reset(seeds)]
    for _ in range(steps):
        o, _, _ = b.step(np.zeros((b.core.settings.n, 1), np.float32), restart=False)
        obs.append(o)
    return np.array(obs)


def test_a_gauge_without_errors_previews_the_plants_force_steps_and_each_error_does_what_it_says():
    dfl = np.zeros(100)
    dfl[30:] += 5e4
    dfl[70:] -= 2e4
    rng = np.random.default_rng(0)
    exact = GaugeSettings(transport_s=0.0, speed_error=0.0, force_model_error=0.0, noise_n=0.0)
    assert np.array_equal(gauge_force(dfl, rng, 5e-4, exact), dfl)
    # a late reading: every change arrives `shift` samples after the preview says (here a fixed 10-sample shift)
    late = GaugeSettings(transport_s=5e-3, speed_error=0.5, force_model_error=0.0, noise_n=0.0)
    z = np.random.default_rng(1).standard_normal()
    shift = int(round(5e-3 * 0.5 * z / 5e-4))
    got = gauge_force(dfl, np.random.default_rng(1), 5e-4, late)
    assert np.flatnonzero(np.diff(got)).tolist() == [29 + shift, 69 + shift]
    # a force model's error scales each change, not the course's level
    sized = gauge_force(dfl, np.random.default_rng(2), 5e-4, GaugeSettings(speed_error=0.0, noise_n=0.0))
    jumps = np.diff(sized)[[29, 69]]
    assert np.all(np.abs(jumps / np.array([5e4, -2e4]) - 1) < 0.6) and not np.allclose(jumps, [5e4, -2e4])


def test_an_exact_preview_is_the_default_and_a_measured_one_changes_only_the_force_preview():
    seeds = [120000, 120001]
    base, exact, measured = (_run_zero(_batch(g), seeds) for g in (None, "exact", "measured"))
    assert np.array_equal(base, exact)
    names = _batch("exact").core.obs_names
    force = [j for j, n in enumerate(names) if n.startswith("preview_force_")]
    rest = [j for j in range(len(names)) if j not in force]
    assert np.array_equal(base[..., rest], measured[..., rest])  # the plant, the sensors and the schedule unchanged
    assert not np.array_equal(base[..., force], measured[..., force])
    assert np.array_equal(measured, _run_zero(_batch("measured"), seeds))  # the same seed, the same bytes


def test_the_measured_preview_has_no_eccentricity_unless_asked():
    b = _batch({"noise_n": 0.0, "force_model_error": 0.0, "speed_error": 0.0}, n=1)
    core = b.core
    b.reset([120002])
    df, _ = core.preview(np.array([0]))
    assert np.all(df == 0.0)  # no force step within 20 ms of the start: the exact preview holds the eccentricity
    e = _batch("exact", n=1)
    e.reset([120002])
    assert np.any(e.core.preview(np.array([0]))[0] != 0.0)


def test_a_failed_gauge_misses_every_change_ahead_and_touches_nothing_else():
    """`failed: true`: the force preview holds the episode's first reading (every channel zero change, all the
    episode, force steps or not), the plant, the sensors and the schedule as with a working gauge."""
    dfl = np.zeros(50)
    dfl[20:] += 4e4
    assert np.array_equal(gauge_force(dfl, np.random.default_rng(0), 5e-4, GaugeSettings(failed=True)), np.zeros(50))
    seeds = [120000, 120001]
    measured, failed = (_run_zero(_batch(g), seeds, steps=1999) for g in ("measured", {"failed": True}))
    names = _batch("measured").core.obs_names
    force = [j for j, n in enumerate(names) if n.startswith("preview_force_")]
    rest = [j for j in range(len(names)) if j not in force]
    assert np.array_equal(measured[..., rest], failed[..., rest])
    assert np.all(failed[..., force] == 0.0) and np.any(measured[..., force] != 0.0)


@pytest.mark.parametrize("value, needle", [("foo", "preview_gauge"), ({"speed_error": -1.0}, "speed_error"),
                                           ({"noise_n": float("nan")}, "noise_n"), ({"lag": 1}, "lag"),
                                           ({"failed": "yes"}, "failed")])
def test_a_bad_gauge_is_refused_in_one_line_naming_it(value, needle):
    with pytest.raises(ValueError, match=needle) as err:
        _batch(value)
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match=needle):
        gauge_settings(value)


def test_the_feedforward_reads_the_channels_back_as_the_observation_scaled_them():
    for scale, q in (("load_force", np.array([-3e5, -1.0, 0.0, 2e3, 8e5])),
                     ("error", np.array([-4e-3, -1e-7, 0.0, 3e-6, 1e-4]))):
        y = slog(q, *OBS_SCALES[scale][2:]).astype(np.float32)
        assert np.allclose(unslog(y, scale), q, rtol=1e-5, atol=1e-3 * OBS_SCALES[scale][2])


def test_a_feedforward_with_zero_gains_adds_nothing_and_a_bad_gain_is_refused():
    ctrl = load_controller("pid-pf-preview", task="rolling", version="v1")
    zero = PreviewFeedforward("zero", np.zeros(len(FF_CHANNELS)), ctrl.env_kwargs["actions"]["residual_gains"])
    zero.task = ROLLING
    b = _batch("measured", n=3)
    obs = b.reset([120000, 120001, 120002])
    assert np.all(zero.predict(obs)[0] == 0.0)
    with pytest.raises(ValueError, match="17 finite"):
        PreviewFeedforward("bad", [1.0, float("inf")] + [0.0] * 15, [1.0, 1.0, 1.0, 1.0])


def _zero_action_costs(env_kwargs, seeds):
    b = EpisodeBatch("MillVib-Valve-v1", len(seeds), **resolve_named_gains_for({"config": "rolling", **env_kwargs},
                                                                               ROLLING, "v1"))
    b.reset(seeds)
    while True:
        _, dones, infos = b.step(np.zeros((len(seeds), 1), np.float32), restart=False)
        if dones.all():
            return np.array([i["severity"] for i in infos]), b


def test_the_environments_feedforward_under_a_zero_residual_is_the_classical_preview_controller():
    ctrl = load_controller("pid-pf-preview", task="rolling", version="v1")
    ctrl.task = ROLLING
    seeds = [120003, 120004, 120005]
    kw = copy.deepcopy(ctrl.env_kwargs)
    kw["observation"]["preview_gauge"] = "measured"
    b = EpisodeBatch("MillVib-Valve-v1", len(seeds), **resolve_named_gains_for({"config": "rolling", **kw},
                                                                               ROLLING, "v1"))
    obs = b.reset(seeds)
    while True:
        obs, dones, infos = b.step(ctrl.predict(obs)[0], restart=False)
        if dones.all():
            break
    classical = np.array([i["severity"] for i in infos])
    kw["actions"] = {**kw["actions"], "residual_feedforward": ctrl.feedforward_gains(), "residual_range_v": 10.0}
    in_env, b2 = _zero_action_costs(kw, seeds)
    # the same controller; the classical one's command passes through a float32 action, the environment's does not
    assert np.allclose(in_env, classical, rtol=1e-5)
    assert np.any(b2.core.u_ff != 0.0)
    kw["actions"]["residual_feedforward"] = {c: 0.0 for c in FF_CHANNELS}
    plain, _ = _zero_action_costs(kw, seeds)
    assert np.all(np.abs(plain - classical) > 1e-4 * classical)  # the feedforward is what made the difference


@pytest.mark.parametrize("ff, needle", [({"pressure": 1.0}, "signed-log channels only"),
                                        ({"preview_force_3": 1.0}, "does not carry"),
                                        ({"load_force": float("nan")}, "residual_feedforward.load_force"),
                                        ([1.0], "a mapping of observation channel")])
def test_a_bad_feedforward_is_refused_in_one_line_naming_it(ff, needle):
    kw = preview_env_kwargs(range_v=10.0)
    kw["actions"]["residual_feedforward"] = ff
    with pytest.raises(ValueError, match=needle):
        EpisodeBatch("MillVib-Valve-v1", 1, **resolve_named_gains_for({"config": "rolling", **kw}, ROLLING, "v1"))


def test_a_feedforward_outside_a_residual_environment_is_refused():
    import gymnasium as gym
    with pytest.raises(ValueError, match="residual valve"):
        gym.make("MillVib-Valve-v1", config="rolling", actions={"residual_feedforward": {"load_force": 1e-6}})


ORACLES = {"pid-oracle", "lqr-oracle", "pid-pf-oracle", "mpc-oracle", "mpc-preview"}


def test_every_baseline_declares_a_known_set_and_the_oracles_are_the_ones_that_read_the_plant():
    for name, b in REGISTRY.items():
        assert label(b.information.split("+")) == b.information
        assert is_oracle(b.information) == (name in ORACLES), name
    assert list(ATOMS)[0] == "loop"


def test_an_agents_set_is_read_off_its_observation():
    student = load_controller("dagger-residual-preview-rolling")
    assert from_env_kwargs(student.env_kwargs) == "loop+force+schedule+gauge"
    assert from_env_kwargs({"observe_phase": True}) == "loop+pump"
    assert from_env_kwargs({}, reads_plant=True) == "loop+params+state"


def test_a_sets_classical_controller_reads_the_same_and_its_bound_previews_nothing_more():
    sets = {"pid": "loop", "ff": "loop+force", "pff": "loop+force+schedule+gauge", "orc": "loop+params",
            "mpc": "loop+force+pump+params+state", "mpcp": "loop+force+schedule+gauge+pump+params+state"}
    assert classical_candidates("loop+force", sets) == ["pid", "ff"]  # it may do what a PID does, and more
    assert classical_candidates("loop+pump", sets) == ["pid"]
    assert bound_candidates("loop", sets) == ["orc", "mpc"]
    assert bound_candidates("loop+force+schedule+gauge", sets) == ["mpcp"]


def _recs(costs, key_scale=1.0):
    return [{"seed": k, "cost": c, "severity_mm_s": c * key_scale, "tracking_rms_um": 10.0 * c} for k, c in
            enumerate(costs)]


def test_a_bound_beaten_by_a_controller_of_its_set_is_reported_as_no_bound():
    rng = np.random.default_rng(0)
    ref = 1.0 + rng.random(60)
    result = {"records": {"pid": _recs(ref), "student": _recs(0.8 * ref), "mpc": _recs(0.9 * ref)},
              "controllers": {n: {"cost_mean": 0.0} for n in ("pid", "student", "mpc")}}
    for n, recs in result["records"].items():
        result["controllers"][n]["cost_mean"] = float(np.mean([r["cost"] for r in recs]))
    sets = {"pid": "loop", "student": "loop", "mpc": "loop+params+state"}
    info = information_verdict(result, sets, baselines={"pid", "mpc"})
    assert info["loop"]["classical"] == "pid" and info["loop"]["bound"] == "mpc"
    assert info["loop"]["bound_holds"] is False and info["loop"]["beaten_by"] == ["student"]
    assert info["loop"]["room_mean"] == pytest.approx(0.1)
    v = result["controllers"]["student"]["same_information"]
    assert v["classical"] == "pid" and v["cost"]["ci"][1] < 0 and not v["tracking_flag"]


def test_a_controller_that_buys_severity_with_tracking_is_flagged():
    ref = np.linspace(1.0, 2.0, 40)
    quiet = [{"seed": k, "cost": c, "severity_mm_s": 0.5 * c, "tracking_rms_um": 13.0 * c} for k, c in
             enumerate(ref)]
    result = {"records": {"pid": _recs(ref), "quiet": quiet},
              "controllers": {"pid": {"cost_mean": 1.5}, "quiet": {"cost_mean": 1.5}}}
    information_verdict(result, {"pid": "loop", "quiet": "loop"}, baselines={"pid"})
    assert result["controllers"]["quiet"]["same_information"]["tracking_flag"]


def test_the_benchmark_gives_each_row_its_set_and_each_set_its_classical_controller():
    result = run_benchmark(["pid-pf-robust", "pid-pf-ff", "pid-pf-preview", "dagger-residual-preview-rolling"],
                           task="rolling", episodes=3, progress=False, env_version="v1")
    ctrls = result["controllers"]
    assert ctrls["pid-pf-preview"]["information"] == "loop+force+schedule+gauge"
    assert result["information"]["loop+force+schedule+gauge"]["classical"] == "pid-pf-preview"
    assert ctrls["dagger-residual-preview-rolling"]["same_information"]["classical"] == "pid-pf-preview"
    assert "same_information" not in ctrls["pid-pf-preview"]  # the classical controller of its own set
    assert result["information"]["loop"]["classical"] == "pid-pf-robust"
    assert result["information"]["loop+force"]["classical"] in ("pid-pf-ff", "pid-pf-robust")  # the cheaper
    assert result["preview"] == "measured"
    with pytest.raises(ValueError, match="--preview"):
        run_benchmark(["pid-pf-robust"], task="rolling", episodes=2, progress=False, env_version="v1",
                      preview="perfect")


def test_the_benchmark_measures_the_preview_of_its_readers_and_can_give_it_exact():
    kw = dict(task="rolling", episodes=2, progress=False, env_version="v1")
    measured = run_benchmark(["pid-pf-robust", "pid-pf-preview"], **kw)
    exact = run_benchmark(["pid-pf-robust", "pid-pf-preview"], preview="exact", **kw)
    assert measured["records"]["pid-pf-robust"] == exact["records"]["pid-pf-robust"]
    assert measured["records"]["pid-pf-preview"] != exact["records"]["pid-pf-preview"]
    assert copy.deepcopy(exact["controllers"]["pid-pf-preview"]["information"]) == "loop+force+schedule+gauge"
    failed = run_benchmark(["pid-pf-robust", "pid-pf-preview"], preview="failed", **kw)
    assert failed["preview"] == "failed" and failed["records"]["pid-pf-robust"] == exact["records"]["pid-pf-robust"]
    assert failed["records"]["pid-pf-preview"] not in (measured["records"]["pid-pf-preview"],
                                                       exact["records"]["pid-pf-preview"])


def test_the_benchmarks_preview_overrides_what_a_readers_own_settings_say():
    """A controller whose own environment reads the measured preview runs on the exact one under
    ``--preview exact`` (and the reverse): the benchmark's setting is the one every preview reader gets."""
    from millvib_env.evaluation.benchmark.lineup import _preview_kwargs

    ctrl = load_controller("pid-pf-preview", task="rolling", version="v1")
    ctrl.env_kwargs["observation"]["preview_gauge"] = "measured"
    assert _preview_kwargs({"ff": ctrl}, "exact") == {"ff": {"observation": {"preview_gauge": "exact"}}}
    plain = load_controller("pid-pf-robust", task="rolling", version="v1")
    assert _preview_kwargs({"pid": plain}, "measured") == {}


def test_the_per_plant_preview_search_runs_each_plant_as_alone_and_never_ends_above_its_start():
    from millvib_env.tuning.search import tune_preview_per_plant

    start = load_controller("pid-pf-preview", task="rolling", version="v1").gains
    both = tune_preview_per_plant([120003, 120004], task=ROLLING, start=start, iters=1)
    alone = tune_preview_per_plant([120004], task=ROLLING, start=start, iters=1)
    assert both["gains"][1] == alone["gains"][0] and both["cost"][1] == alone["cost"][0]
    assert all(c <= c0 for c, c0 in zip(both["cost"], both["start_cost"]))
    with pytest.raises(ValueError, match="start = .* 17 finite gains"):
        tune_preview_per_plant([120003], task=ROLLING, start=start[:3])
