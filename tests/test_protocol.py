"""The evaluation protocol: statistics with known answers, the JSON schema, multi-seed agents, determinism."""
import json
import shutil

import numpy as np
import pytest

from millvib_env._paths import agents_dir
from millvib_env.cli import main as cli_main
from millvib_env.catalog.agents import agent_seeds, list_agents
from millvib_env.catalog.factory import load_controller
from millvib_env.evaluation.benchmark import public_json, run_benchmark
from millvib_env.evaluation.stats import cvar, interval, iqm, normalized_score, paired_difference, worst
from millvib_env.tasks import get_task

#: per controller, what `millvib benchmark --json` promises (README, "Benchmark JSON")
METRICS = ("cost_mean", "cost_iqm", "cost_cvar20", "cost_worst", "severity_mean", "tracking_rms_um_mean")
SCHEMA = set(METRICS) | {f"{m}_ci" for m in METRICS} | {"diverged_rate", "n_seeds", "episodes"}


def test_cvar_iqm_and_worst_of_known_samples():
    x = np.arange(1.0, 11.0)  # 1..10
    assert cvar(x) == pytest.approx(9.5)  # the worst 20 %: 10 and 9
    assert cvar(x, 0.05) == 10.0  # at least one episode
    assert iqm(np.arange(8.0)) == pytest.approx(3.5)  # mean of 2, 3, 4, 5
    assert iqm([1, 1, 1, 1, 1, 1, 100, -100]) == pytest.approx(1.0)  # outliers trimmed
    assert worst(x) == 10.0


def test_the_interval_covers_the_true_mean_at_about_its_level():
    rng = np.random.default_rng(7)
    hits = 0
    for _ in range(60):
        samples = [rng.lognormal(0.0, 0.5, 40) for _ in range(3)]  # three seeds, 40 plants each
        lo, hi = interval(samples)
        hits += lo <= np.exp(0.125) <= hi  # E[lognormal(0, 0.5)]
        assert lo <= np.mean(np.concatenate(samples)) <= hi
    assert hits >= 51  # 95 % nominal: 60 trials, P(hits < 51) ~ 0.3 %


def test_intervals_are_seeded_and_degenerate_samples_give_a_point():
    x = [np.random.default_rng(1).normal(5, 1, 30)]
    assert interval(x) == interval(x)
    assert interval([[2.0, 2.0, 2.0, 2.0]]) == [2.0, 2.0]
    lo, hi = interval(x, cvar)
    assert lo <= cvar(x[0]) <= hi


def test_paired_difference_and_score_of_a_known_case():
    ref = np.linspace(1.0, 2.0, 50)
    better = [0.9 * ref, 0.8 * ref]  # two seeds: 10 % and 20 % cheaper on every plant
    pd = paired_difference(better, ref)
    assert pd["cost_diff_rel"] == pytest.approx(-0.15)
    assert pd["ci"][0] < -0.15 < pd["ci"][1] < 0 and pd["p_improvement"] == 1.0
    oracle = 0.85 * ref
    ns = normalized_score(better, ref, oracle)
    assert ns["score"] == pytest.approx(1.0) and not ns["one_worse_than_zero"]
    assert normalized_score([ref], ref, oracle)["score"] == pytest.approx(0.0)
    assert normalized_score([ref], ref, 1.1 * ref)["one_worse_than_zero"]
    with pytest.raises(ValueError, match="same plants"):
        paired_difference([ref[:10]], ref)


def test_the_paired_cvar_difference_sees_a_worst_case_gain_that_the_mean_hides():
    rng = np.random.default_rng(4)
    ref = rng.uniform(1.0, 2.0, 200)
    worst_plants = ref >= np.quantile(ref, 0.8)
    seeds = [np.where(worst_plants, 0.7 * ref, ref + 0.02) + rng.normal(0, 0.01, ref.size) for _ in range(3)]
    pd = paired_difference(seeds, ref)
    # the known answer: the worst 20 % of plants are 30 % cheaper, the others 1-2 % dearer
    assert pd["cvar20_diff_rel"] == pytest.approx(cvar(np.concatenate(seeds)) / cvar(ref) - 1)
    assert pd["cvar20_ci"][0] <= pd["cvar20_diff_rel"] <= pd["cvar20_ci"][1] < -0.05
    assert pd["ci"][0] < pd["cvar20_ci"][1]  # the mean gains far less
    same = paired_difference([ref], ref)
    assert same["cvar20_diff_rel"] == 0.0 and same["cvar20_ci"] == [0.0, 0.0]


def test_the_json_schema_and_the_comparisons(tmp_path):
    out = tmp_path / "bench.json"
    rc = cli_main(["benchmark", "--task", "rolling", "--controllers", "pid-robust", "pid-oracle", "pid-paper",
                   "--episodes", "6", "--quiet", "--json", str(out), "--seed", "3"])
    assert rc == 0
    data = json.loads(out.read_text())
    assert {"controllers", "task", "seed", "episodes", "env_id", "plants", "all_seeds", "env_version",
            "loop"} <= set(data)
    assert data["seed"] == 3 and data["episodes"] == 6 and len(data["plants"]) == 6
    # the loop as commissioned by default: its settings, and what each controller asked of the actuator
    assert data["env_version"] == "v1" and data["env_id"] == "MillVib-GainSchedule-v1"
    loop = data["loop"]
    assert loop["kind"] == "digital" and loop["rate_hz"] == 2000 and loop["delay_samples"] == 1
    assert loop["u_max_v"] == 10 and loop["valve"]["natural_frequency_hz"] == 150 and "sensors" in loop
    for name, s in data["controllers"].items():
        assert set(s["command"]["max_abs_v"]) == {"median", "p95", "max"}, name
        assert s["command"]["max_abs_v"]["max"] <= loop["u_max_v"], name  # no command leaves the range
        assert 0.0 <= s["command"]["share_at_limit"] <= 1.0
        assert s["spool_stroke_m"]["max"] <= loop["valve"]["xv_max_m"] * (1 + 1e-12)
        assert s["n_diverged"] == 0 and {"peak_flow_ratio", "pressure_pa"} <= set(s)
    for name, s in data["controllers"].items():
        assert SCHEMA <= set(s), name
        assert s["n_seeds"] == 1 and s["episodes"] == 6
        for m in METRICS:
            lo, hi = s[f"{m}_ci"]
            assert lo <= s[m] <= hi or lo == hi == s[m], (name, m)
    pr = data["controllers"]["pid-paper"]["paired_vs_pid_robust"]
    assert set(pr) == {"cost_diff_rel", "ci", "p_improvement", "cvar20_diff_rel", "cvar20_ci"} and len(pr["ci"]) == 2
    assert "paired_vs_pid_robust" not in data["controllers"]["pid-robust"]
    assert data["controllers"]["pid-oracle"]["normalized_score"]["score"] == pytest.approx(1.0)
    assert data["controllers"]["pid-robust"]["normalized_score"]["score"] == pytest.approx(0.0)
    # the reference (pid-pf-robust by default) is run although --controllers leaves it out
    assert data["reference"] == "pid-pf-robust" and "pid-pf-robust" in data["controllers"]
    keys = {"cost_diff_rel", "ci", "p_improvement", "cvar20_diff_rel", "cvar20_ci"}
    for name, s in data["controllers"].items():
        others = {"pid-pf-robust", "pid-robust"} - {name}
        assert set(s["paired"]) == others, name
        assert all(set(d) == keys for d in s["paired"].values())
    # every row carries what it reads, and each set its classical controller and bound
    assert {s["information"] for s in data["controllers"].values()} == {"loop", "loop+params"}
    assert data["information"]["loop"]["classical"] in ("pid-robust", "pid-paper", "pid-pf-robust")
    assert data["information"]["loop"]["bound"] == "pid-oracle" and data["preview"] == "measured"
    paper = data["controllers"]["pid-paper"]
    assert paper["same_information"]["classical"] == data["information"]["loop"]["classical"]
    assert paper["paired"]["pid-robust"] == paper["paired_vs_pid_robust"]
    assert paper["paired"]["pid-pf-robust"]["cost_diff_rel"] > 0  # the paper's PID is the dearer


def test_the_reference_can_be_chosen_and_an_unknown_one_is_refused_in_one_line(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert cli_main(["benchmark", "--task", "rolling", "--controllers", "pid-paper", "--reference", "pid-robust",
                     "--episodes", "3", "--quiet", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["reference"] == "pid-robust" and set(data["controllers"]) == {"pid-robust", "pid-paper"}
    capsys.readouterr()
    assert cli_main(["benchmark", "--task", "rolling", "--reference", "pid-bogus", "--episodes", "3",
                     "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pid-bogus" in err[0]


def test_the_same_seed_gives_the_same_json_bytes(tmp_path):
    args = ["benchmark", "--task", "change", "--controllers", "pid-robust", "pid-nominal", "--episodes", "4",
            "--quiet"]
    for name in ("a", "b"):
        assert cli_main(args + ["--json", str(tmp_path / f"{name}.json")]) == 0
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert cli_main(args + ["--seed", "1", "--json", str(tmp_path / "c.json")]) == 0
    a, c = (json.loads((tmp_path / f"{n}.json").read_text()) for n in "ac")
    assert not set(a["plants"]) & set(c["plants"])


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
def test_all_seeds_pools_every_training_seed_of_an_agent(tmp_path):
    two = [n for n in list_agents("startup") if len(agent_seeds(n)) >= 2]
    if not two:
        pytest.skip("no shipped startup agent has two seeds")
    src = agents_dir() / two[0]
    agent = tmp_path / "agent"
    for s in agent_seeds(two[0])[:2]:
        shutil.copytree(src / f"seed-{s}", agent / f"seed-{s}")
    kw = dict(task="startup", episodes=4, progress=False, scenarios=False)
    quick = run_benchmark(["pid-robust", str(agent)], **kw)
    full = run_benchmark(["pid-robust", str(agent)], all_seeds=True, **kw)
    assert quick["controllers"][str(agent)]["n_seeds"] == 1
    s = full["controllers"][str(agent)]
    assert s["n_seeds"] == 2 and s["episodes"] == 4 and len(full["records"][str(agent)]) == 8
    assert [p["seed"] for p in s["per_seed"]] == agent_seeds(two[0])[:2]
    first = [r["cost"] for r in full["records"][str(agent)] if r["agent_seed"] == s["per_seed"][0]["seed"]]
    assert first == [r["cost"] for r in quick["records"][str(agent)]]
    assert public_json(full)["all_seeds"] is True


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
def test_a_benchmark_of_baselines_never_imports_torch_nor_scipy_signal(tmp_path):
    """Nor scipy.signal, once its filters are designed on this machine (`envs.filter_design`): here, by an episode
    of each controller in this process, which shares the child's cache folder."""
    import subprocess
    import sys

    from millvib_env.catalog import load_controller
    from millvib_env.evaluation.evaluate import run_episodes

    for name in ("pid-robust", "pid-adaptive"):
        run_episodes(load_controller(name, "rolling"), [20000], env_kwargs={"episode_s": 0.1})
    code = ("import sys; from millvib_env.cli import main; "
            "rc = main(['benchmark', '--task', 'rolling', '--controllers', 'pid-robust', 'pid-adaptive', '--episodes', "
            "'2', '--quiet', '--json', sys.argv[1]]); "
            "print(rc, 'torch' in sys.modules, 'stable_baselines3' in sys.modules, 'scipy.signal' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code, str(tmp_path / "b.json")], capture_output=True, text=True,
                         timeout=300)
    assert run.stdout.strip().splitlines()[-1] == "0 False False False", run.stdout + run.stderr


def test_an_evaluation_starts_one_episode_per_plant_and_none_after_the_last(monkeypatch):
    """The step that ends the last episodes restarts no environment: a new episode's draw (its plant, its settled
    state) would be discarded. The records are those of the loop that restarts them, and an environment left
    done says so in one line if it is stepped again."""
    from millvib_env.catalog import load_controller
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.envs.core import MillVibCore
    from millvib_env.evaluation.evaluate import run_episodes

    started = []
    reset_env, step = MillVibCore.reset_env, EpisodeBatch.step

    def counted(self, i, *args, **kwargs):
        started.append(i)
        return reset_env(self, i, *args, **kwargs)

    monkeypatch.setattr(MillVibCore, "reset_env", counted)
    plants = [20000, 20001, 20002]
    for name in ("pid-robust", "pid-adaptive"):
        started.clear()
        records = run_episodes(load_controller(name, "rolling"), plants, env_kwargs={"episode_s": 0.1})
        assert sorted(started) == [0, 1, 2], (name, started)
        with monkeypatch.context() as m:  # every done environment restarted, as a vector env does
            m.setattr(EpisodeBatch, "step", lambda self, actions, restart=True: step(self, actions))
            started.clear()
            again = run_episodes(load_controller(name, "rolling"), plants, env_kwargs={"episode_s": 0.1})
            assert sorted(started) == [0, 0, 1, 1, 2, 2]
        assert again == records, name

    batch = EpisodeBatch("MillVib-Valve-v1", 2, config="rolling", episode_s=0.1)
    batch.reset([20000, 20001])
    zero = np.zeros((2, 1), dtype=np.float32)
    for _ in range(batch.core.settings.max_steps - 1):
        batch.step(zero, restart=False)
    _, dones, _ = batch.step(zero, restart=False)
    assert dones.all()
    with pytest.raises(ValueError, match=r"^step\(\) before reset\(\)"):
        batch.step(zero)


def test_scenarios_in_one_batch_give_each_scenarios_own_episode():
    """`run_episodes` takes one scenario per seed; for a controller whose environments do not touch each other
    (`batch_exact`: the baselines, the MPC bounds), a batch of the named scenarios gives the records of one
    scenario at a time, as the benchmark's scenario rows need. A list of the wrong length is refused in one
    line, before any work."""
    from millvib_env.catalog import load_controller
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.evaluation.evaluate import run_episodes

    names = ["nominal", "low-damping", "high-leakage"]
    short = {"episode_s": 0.1}
    for name in ("pid-adaptive", "mpc-oracle"):
        ctrl = load_controller(name, "startup", version="v1")
        assert ctrl.batch_exact
        together = run_episodes(ctrl, [20000] * 3, scenario=names, env_kwargs=short)
        alone = [run_episodes(load_controller(name, "startup", version="v1"), [20000], scenario=sc,
                              env_kwargs=short)[0]
                 for sc in names]
        assert [r["scenario"] for r in together] == names
        assert together == alone, name
    with pytest.raises(ValueError, match=r"^scenario = \['nominal'\] is invalid: .* a list of 2 \(one per seed\)$"):
        run_episodes(load_controller("pid-robust", "startup"), [1, 2], scenario=["nominal"])
    batch = EpisodeBatch("MillVib-GainSchedule-v1", 2, config="startup")
    with pytest.raises(ValueError, match=r"^options = .* is invalid: a dict of reset options, or a list of 2"):
        batch.reset([1, 2], [{"scenario": "nominal"}])


def test_episode_records_and_the_csv_columns_have_one_home():
    from millvib_env.catalog import load_controller
    from millvib_env.evaluation.evaluate import CSV_FIELDS, RECORD_FIELDS, run_episodes
    from millvib_env.evaluation.sweep import RANGES

    assert set(CSV_FIELDS) <= set(RECORD_FIELDS)
    for name in ("pid-robust", "pid-adaptive"):  # the adaptive PID adds its estimator's errors
        rec = run_episodes(load_controller(name), [20000])[0]
        assert set(rec) <= set(RECORD_FIELDS), set(rec) - set(RECORD_FIELDS)
    assert set(RANGES) <= set(RECORD_FIELDS)  # a sweep's drawn parameters are record columns


def test_a_controller_of_your_own_is_benchmarked_beside_the_names():
    """A `Controller` object in the list (here a fixed-gain PID with gains of one's own): its records are its own
    episodes on the benchmark's plants, it is compared with the reference like any other and written to the JSON;
    a taken name, an environment of another version and Ray are refused in one line."""
    from millvib_env import PIDGains
    from millvib_env.control.policies import FixedGainPolicy
    from millvib_env.evaluation.benchmark import format_table
    from millvib_env.evaluation.evaluate import run_episodes

    mine = FixedGainPolicy("my-pid", PIDGains(1.5e6, 2e3, 40.0))
    mine.env_id = "MillVib-GainSchedule-v1"
    with pytest.raises(ValueError, match="description = .* is invalid: a string"):  # a GainMap where it once was
        FixedGainPolicy("my-pid", PIDGains(1.5e6, 2e3, 40.0), object())
    kw = dict(task="startup", episodes=3, scenarios=False, progress=False)
    result = run_benchmark(["pid-robust", mine], **kw)
    assert "pid-pf-robust" in result["controllers"]["my-pid"]["paired"]
    own = run_episodes(mine, result["plants"], task="startup")
    assert [r["cost"] for r in result["records"]["my-pid"]] == [r["cost"] for r in own]
    # on another task it runs in that task's environment; the object given is left as it was
    rolling = run_benchmark(["pid-robust", mine], **{**kw, "task": "rolling", "episodes": 2})
    own = run_episodes(mine, rolling["plants"], task="rolling")
    assert [r["cost"] for r in rolling["records"]["my-pid"]] == [r["cost"] for r in own]
    assert mine.task is None
    assert "my-pid" in format_table(result) and "my-pid" in public_json(result)["controllers"]
    taken = FixedGainPolicy("pid-robust", PIDGains(1e6, 1.0))
    taken.env_id = "MillVib-GainSchedule-v1"
    for controllers, extra, message in (([taken], {}, r"controllers\[0\]\.name = 'pid-robust' is invalid"),
                                        ([FixedGainPolicy("my-v0", PIDGains(1e6, 1.0))], {}, "version v1"),
                                        ([mine], {"ray": ""}, "ray = '' is invalid"),
                                        ([mine], {"jobs": 2}, "jobs = 2 is invalid"),
                                        (["pid-robust", 3], {}, r"controllers\[1\] = 3 is invalid")):
        with pytest.raises(ValueError, match=message) as err:
            run_benchmark(controllers, **{**kw, **extra})
        assert "\n" not in str(err.value)


def test_a_benchmark_in_worker_processes_equals_the_one_process_run():
    """`--jobs N`: controllers x chunks of episodes as jobs in local worker processes, the same numbers (an
    agent's jobs are the same function, `episode_records`, and are checked on Ray in tests/test_ray.py)."""
    kw = dict(task="startup", episodes=2, progress=False, scenarios=False, reference="pid-robust")
    one = public_json(run_benchmark(["pid-robust", "pid-paper"], **kw))
    two = public_json(run_benchmark(["pid-robust", "pid-paper"], jobs=2, **kw))
    assert one == two and set(one["controllers"]) == {"pid-robust", "pid-paper"}
    # the named scenarios run as jobs too, one per controller, and come back in the controllers' order
    kw["scenarios"] = True
    one = public_json(run_benchmark(["pid-robust", "pid-paper"], **kw))
    two = public_json(run_benchmark(["pid-robust", "pid-paper"], jobs=2, **kw))
    assert one == two and list(two["scenarios"]) == ["pid-robust", "pid-paper"] and two["scenarios"]["pid-paper"]
    with pytest.raises(ValueError, match="jobs = 0 is invalid"):
        run_benchmark(["pid-robust"], jobs=0, **kw)


def test_a_benchmark_resolves_each_name_once_and_its_jobs_carry_specs(monkeypatch):
    """Each controller name is looked up once in the benchmark's process (`resolve_controller`), every training seed
    of an agent included; a job carries the spec, and the controller a worker builds from it runs the episodes the
    controller loaded by name runs."""
    from millvib_env.catalog import factory
    from millvib_env.catalog.factory import build_controller, resolve_controller
    from millvib_env.evaluation.benchmark import jobs, lineup

    looked_up: list[str] = []

    def counting(name, *a, **kw):
        looked_up.append(name)
        return resolve_controller(name, *a, **kw)

    monkeypatch.setattr(lineup, "resolve_controller", counting)
    sent: list = []
    monkeypatch.setattr(jobs, "run_jobs", lambda fn, js, **kw: sent.extend(js) or [fn(**j) for j in js])
    kw = dict(task="rolling", episodes=2, progress=False, scenarios=False, all_seeds=True, reference="pid-pf-robust")
    result = public_json(run_benchmark(["pid-robust", "ppo-gain-pf-v1-rolling"], jobs=2, **kw))
    assert sorted(looked_up) == ["pid-pf-robust", "pid-robust", "ppo-gain-pf-v1-rolling"]
    agent_jobs = [j for j in sent if j["name"] == "ppo-gain-pf-v1-rolling"]
    assert len(agent_jobs) == 3 and sorted(j["spec"].seed for j in agent_jobs) == [0, 1, 2]
    assert all(isinstance(j["spec"], factory.ControllerSpec) and "task" not in j for j in sent)
    assert set(result["controllers"]) == {"pid-pf-robust", "pid-robust", "ppo-gain-pf-v1-rolling"}
    spec = resolve_controller("ppo-gain-pf-v1-rolling", get_task("rolling"), seed=1)
    by_name = load_controller("ppo-gain-pf-v1-rolling", "rolling", seed=1)
    assert build_controller(spec).seed == by_name.seed == 1
    with pytest.raises(ValueError, match="no training seed 7"):
        spec.for_seed(7)
    with pytest.raises(ValueError, match="spec"):
        build_controller("ppo-gain-pf-v1-rolling")


def test_jobs_auto_runs_worker_processes_only_where_they_pay(monkeypatch):
    """`--jobs auto` (the CLI's default): processes where an MPC bound or two agent runs take part on enough
    plants, never more than the usable cores, MILLVIB_NUM_THREADS or AUTO_JOBS_MAX; one process for the classical
    controllers, for one agent (all its plants are one job) and for a few plants."""
    from millvib_env.evaluation.benchmark import jobs as bm
    from millvib_env.threads import THREADS_ENV

    monkeypatch.delenv(THREADS_ENV, raising=False)
    monkeypatch.setattr(bm, "usable_cores", lambda: 8)
    classical = [(n, None) for n in ("pid-paper", "pid-robust", "pid-adaptive", "pid-pf-robust")]
    mpc, agent = [("mpc-oracle", None)], [("student", 0)]
    assert bm.auto_jobs(classical, 200) == 1
    assert bm.auto_jobs(classical + agent, 200) == 1
    assert bm.auto_jobs(classical + agent + [("student", 1)], 200) == bm.AUTO_JOBS_MAX
    assert bm.auto_jobs(classical + mpc, bm.AUTO_MIN_PLANTS) == bm.AUTO_JOBS_MAX
    assert bm.auto_jobs(classical + mpc, bm.AUTO_MIN_PLANTS - 1) == 1
    monkeypatch.setattr(bm, "usable_cores", lambda: 2)
    assert bm.auto_jobs(classical + mpc, 40) == 2
    monkeypatch.setenv(THREADS_ENV, "1")
    assert bm.auto_jobs(classical + mpc, 40) == 1
    # the API's default stays one process; "auto" there gives the one-process run's numbers
    kw = dict(task="startup", episodes=2, progress=False, scenarios=False, reference="pid-robust")
    assert public_json(run_benchmark(["pid-paper"], jobs="auto", **kw)) == public_json(run_benchmark(["pid-paper"],
                                                                                                      **kw))


@pytest.mark.slow  # draws five figures: seconds
def test_the_benchmarks_and_the_sweeps_figures_keep_every_text_inside_and_their_panels_apart(monkeypatch, tmp_path):
    """The figures are placed at fixed margins (`_figures.panel_grid`), not measured: the planes, the bars and the
    traces of a short benchmark with the default set's longest names, and a sweep's maps over three parameters,
    keep their texts inside and their panels apart (`tests._figures`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import millvib_env.evaluation.benchmark as bench
    from millvib_env.evaluation.benchmark import plots
    from millvib_env.evaluation.sweep import _maps, run_sweep
    from tests._figures import texts_inside_and_panels_apart

    drawn = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path, dpi=100: drawn.append(fig) or path)
    result = bench.run_benchmark(["pid-paper", "pid-pf-robust", "dagger-residual-preview-rolling"], task="rolling",
                                 episodes=2, scenarios=False, progress=False)
    plots._plot_plane(result, tmp_path / "a.png")
    plots._plot_paired_plane(result, tmp_path / "b.png")
    plots._plot_bars(result, tmp_path / "c.png")
    plots._plot_traces(list(result["controllers"]), tmp_path / "d.png", result["plants"][0], scenario=None,
                       task=get_task("rolling"), version="v1")
    drawn.append(_maps(run_sweep(["pid-paper"], 3, params=["c1", "Ct", "beta_e"], progress=False)))
    for fig in drawn:
        texts_inside_and_panels_apart(fig)
        plt.close(fig)


@pytest.mark.slow  # a fresh process and two workers: seconds
def test_a_benchmark_whose_agents_run_in_workers_loads_no_learner_in_the_parent(tmp_path):
    """An agent's network loads at its first use (`AgentPolicy.model`): where every agent run goes to a worker
    process (rolling has no named scenarios), the parent imports neither torch nor SB3, and the numbers are the
    one-process run's."""
    import subprocess
    import sys

    kw = dict(task="rolling", all_seeds=True, episodes=3, progress=False, reference="pid-robust")
    code = ("import sys, json; from millvib_env.evaluation.benchmark import run_benchmark, public_json\n"
            "if __name__ == '__main__':\n"
            f"    r = run_benchmark(['dagger-residual-preview-rolling'], jobs=2, **{kw!r})\n"
            f"    open({str(tmp_path / 'two.json')!r}, 'w').write(json.dumps(public_json(r)))\n"
            "    print('torch' in sys.modules, 'stable_baselines3' in sys.modules)")
    script = tmp_path / "run.py"
    script.write_text(code)
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert run.stdout.strip().splitlines()[-1] == "False False", run.stdout + run.stderr
    one = public_json(run_benchmark(["dagger-residual-preview-rolling"], **kw))
    assert json.loads((tmp_path / "two.json").read_text()) == json.loads(json.dumps(one))


def test_an_episode_with_its_own_plant_pinned_is_that_episode_and_another_plant_changes_it():
    from millvib_env.catalog.factory import load_controller
    from millvib_env.evaluation.evaluate import run_episodes

    ctrl = load_controller("pid-pf-robust", "varied")
    kw = {"episode_s": 0.1}
    plain = run_episodes(ctrl, [320000, 320001], task="varied", env_kwargs=kw)
    own = {k: plain[0][k] for k in ("c1", "Ct", "beta_e", "mt", "FL")}
    pinned = run_episodes(ctrl, [320000, 320001], task="varied", env_kwargs=kw,
                          params=[own, {**own, "c1": 2.0 * own["c1"]}])
    assert pinned[0]["cost"] == plain[0]["cost"]  # its own draw pinned: the same episode
    assert pinned[1]["c1"] == 2.0 * own["c1"] and pinned[1]["cost"] != plain[1]["cost"]
    with pytest.raises(ValueError, match=r"params = .*\(one dict or None per seed\)"):
        run_episodes(ctrl, [320000], task="varied", params=[own, own])


def test_the_benchmark_packages_names_come_from_their_modules_and_its_flags_import_none_of_it():
    """Each public name of `evaluation.benchmark` is its module's own object, every one of `__all__` is found, and
    the CLI's parser (which imports `flags`) loads no other module of the package."""
    import importlib
    import subprocess
    import sys

    import millvib_env.evaluation.benchmark as bench

    stats = {"cvar", "interval", "paired_difference"}
    assert set(bench._MODULE) | stats == set(bench.__all__) and not set(bench._MODULE) & stats
    for name in bench.__all__:
        where = f"{bench.__name__}.{bench._MODULE[name]}" if name in bench._MODULE else "millvib_env.evaluation.stats"
        assert getattr(bench, name) is getattr(importlib.import_module(where), name)
    code = ("import sys, millvib_env.evaluation.benchmark.flags; "
            "print(sorted(m for m in sys.modules if m.startswith('millvib_env.evaluation.benchmark.')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['millvib_env.evaluation.benchmark.flags']"
