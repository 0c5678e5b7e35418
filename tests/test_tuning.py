"""Tuning at scale: an Optuna study in shared storage, worked on by several processes."""

import numpy as np
import pytest

optuna = pytest.importorskip("optuna")


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
def test_two_workers_share_one_study_through_a_journal_file(tmp_path):
    """Two worker processes (forks of the package's fork server, `distributed.run_jobs`), running at once as two
    terminals' `millvib tune --optuna journal:FILE` would, add their trials to one study."""
    from millvib_env.distributed import run_jobs
    from tests._jobs import tune_in_a_shared_study

    storage = f"journal:{tmp_path / 'study.log'}"
    run_jobs(tune_in_a_shared_study, [{"storage": storage, "study_name": "s", "n_trials": 2}] * 2, processes=2)
    from millvib_env.tuning.search import optuna_storage

    study = optuna.load_study(study_name="s", storage=optuna_storage(storage))
    assert len(study.trials) == 4 and study.best_value > 0


def test_a_bad_storage_is_refused():
    from millvib_env.tuning.search import optuna_storage

    with pytest.raises(ValueError, match="--optuna 'somewhere' is invalid"):
        optuna_storage("somewhere")
    for url in ("bogus://", "sqlite:////proc/x.db"):  # an unknown dialect, a file that cannot be opened
        with pytest.raises(ValueError, match="cannot be opened"):
            optuna_storage(url)


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
def test_tuning_into_a_file_leaves_the_shipped_configs_byte_identical_and_keeps_a_better_entry(tmp_path, capsys):
    import yaml

    from millvib_env._paths import config_dir
    from millvib_env.cli import main as cli_main

    def files():
        return {str(p.relative_to(config_dir())): p.read_bytes() for p in (config_dir() / "control").rglob("*.yaml")}

    shipped = files()
    out = tmp_path / "rolling.yaml"
    rc = cli_main(["tune", "--task", "rolling", "--env-version", "v0", "--only", "pid-robust", "--optuna",
                   f"journal:{tmp_path / 'j.log'}", "--trials", "2", "--out", str(out), "--quiet"])
    assert rc == 0
    assert files() == shipped
    printed = capsys.readouterr().out
    tuned = yaml.safe_load(out.read_text())
    ours = yaml.safe_load(shipped["control/rolling.yaml"])
    if "kept the existing entry" in printed:  # a 2-trial study is worse than the shipped tuning
        assert tuned["pid-robust"] == ours["pid-robust"]
    else:
        assert tuned["pid-robust"]["tuning_cost"] <= ours["pid-robust"]["tuning_cost"]
    assert cli_main(["tune", "--task", "rolling", "--only", "pid-robust"]) == 2  # say where it goes
    assert "--out FILE" in capsys.readouterr().err


def test_every_tuned_entry_is_a_registered_baseline_and_every_fixed_gain_set_is_tuned():
    from millvib_env.catalog.registry import REGISTRY
    from millvib_env.tuning.baselines import ENTRIES, SHARED, TUNERS

    assert ENTRIES == tuple(TUNERS) and set(SHARED) <= set(TUNERS) and set(TUNERS) <= set(REGISTRY)
    assert {n for n, b in REGISTRY.items() if b.named_gains and n != "pid-paper"} <= set(TUNERS)


def test_a_run_tunes_every_entry_in_order_each_on_the_one_it_builds_on(monkeypatch):
    """The tuners' wiring, with the searches replaced by stand-ins that record what they were given: pid-pf-ff
    starts from this run's pid-pf-robust, pid-adaptive takes this run's pid-oracle table, and --from-task
    shares the oracles' entries instead of tuning them."""
    from millvib_env.tuning import search as tuning
    from millvib_env.tuning.baselines import ENTRIES, tune_task

    calls = []

    def result(n_gains, tag):
        calls.append(tag)
        return tuning.TuneResult(np.full(n_gains, float(len(calls))), 1.0 + len(calls), np.zeros(n_gains), 2.0, 1)

    monkeypatch.setattr(tuning, "tune", lambda seeds, **k: result(3, ("tune", k.get("params") is not None)))
    monkeypatch.setattr(tuning, "tune_from", lambda starts, seeds, **k: result(starts.shape[1], ("from", starts[0])))
    monkeypatch.setattr(tuning, "tune_lqr", lambda seeds, **k: {"weights": {}, "tuning_cost": 1.0})
    monkeypatch.setattr(tuning, "tune_adaptive",
                        lambda seeds, table=None, **k: {"estimator": {"tau_s": 0.1}, "table_rows": len(table.c1_grid)})
    out = tune_task("startup", grid=2, progress=False, version="v1")
    assert list(out) == list(ENTRIES)
    assert out["pid-adaptive"]["table_rows"] == 2  # this run's 2 x 2 pid-oracle table, not the shipped 5 x 5
    ff_start = next(c[1] for c in calls if c[0] == "from" and len(c[1]) == 5)
    assert np.allclose(ff_start[:4], out["pid-pf-robust"]["log10_gains"])
    shared = tune_task("rolling", only=["pid-oracle", "lqr-oracle", "pid-pf-oracle"], from_task="startup",
                       progress=False, version="v1")
    assert shared == {n: {"from_task": "startup"} for n in ("pid-oracle", "lqr-oracle", "pid-pf-oracle")}
    with pytest.raises(ValueError, match="jobs = 0 is invalid"):
        tune_task("startup", only=["pid-oracle"], grid=2, progress=False, version="v1", jobs=0)


def test_a_tune_of_some_entries_says_what_it_replaces_and_keeps_the_whole_tunes_time(monkeypatch, tmp_path, capsys):
    """`millvib tune --only pid-adaptive`: pid-adaptive's cost is that of the forgetting time it took (the lowest of
    its candidates'), compared with the shipped entry's; the file's wall_time_s stays the whole tune's."""
    import yaml

    from millvib_env.cli import main as cli_main
    from millvib_env.catalog.factory import control_config_path
    from millvib_env.tasks import get_task
    from millvib_env.tuning import baselines

    shipped = yaml.safe_load(control_config_path(get_task("rolling"), "v1").read_text())
    old = min(shipped["pid-adaptive"]["tuning_costs"].values())
    entry = {**shipped["pid-adaptive"], "tuning_costs": {"0.1": old + 1.0, "0.2": old - 0.5}}
    monkeypatch.setattr(baselines, "tune_task", lambda t, only, **k: {"pid-adaptive": entry})
    out = tmp_path / "rolling.yaml"
    assert cli_main(["tune", "--task", "rolling", "--only", "pid-adaptive", "--out", str(out)]) == 0
    assert f"pid-adaptive: replaces {old:.4g} with {old - 0.5:.4g}" in capsys.readouterr().out
    written = yaml.safe_load(out.read_text())
    assert written["wall_time_s"] == shipped["wall_time_s"] and written["pid-adaptive"] == entry
    dearer = {**entry, "tuning_costs": {"0.1": old + 1.0}}
    monkeypatch.setattr(baselines, "tune_task", lambda t, only, **k: {"pid-adaptive": dearer})
    assert cli_main(["tune", "--task", "rolling", "--only", "pid-adaptive", "--out", str(out)]) == 0
    assert "pid-adaptive: kept the existing entry" in capsys.readouterr().out


def test_a_raced_grid_keeps_the_sets_cheapest_on_the_first_plants_with_their_whole_means(monkeypatch):
    """`search.raced_costs`: every set scored on the first quarter of the plants, the cheapest third there (at least
    ten) on the rest; a kept set's mean is `mean_costs`' number exactly (the same episodes in the plants' order), the
    others inf. A grid below `RACE_MIN_SETS`, or fewer plants than `RACE_MIN_PLANTS`, is scored whole."""
    from millvib_env.tuning import search

    rng = np.random.default_rng(0)
    table = rng.random((120, 12)) + np.linspace(0.0, 1.0, 120)[:, None]  # cost of set i on plant j
    calls = []

    def fake(sets, seeds, **kwargs):
        rows = [int(r[0]) for r in np.atleast_2d(sets)]
        calls.append((len(rows), len(seeds)))
        return table[np.ix_(rows, [int(s) for s in seeds])]
    monkeypatch.setattr(search, "episode_costs", fake)
    sets = np.arange(120.0)[:, None]
    out = search.raced_costs(sets, list(range(12)), task=None)
    assert calls == [(120, 3), (40, 9)]  # a quarter of the plants, then a third of the sets on the rest
    kept = np.isfinite(out)
    assert kept.sum() == 40 and np.array_equal(np.flatnonzero(kept), np.sort(np.argsort(table[:, :3].mean(1))[:40]))
    assert np.array_equal(out[kept], table[kept].mean(axis=1))
    calls.clear()
    assert np.array_equal(search.raced_costs(sets[:40], list(range(12)), task=None), table[:40].mean(axis=1))
    assert np.array_equal(search.raced_costs(sets, [0, 1, 2], task=None), table[:, :3].mean(axis=1))
    assert calls == [(40, 12), (120, 3)]


def test_an_interrupted_tune_keeps_its_finished_entries_and_resume_goes_on_to_the_same_file(monkeypatch, tmp_path,
                                                                                           capsys):
    """A Ctrl-C in `millvib tune` keeps the finished entries in the result's journal and says so in its one line;
    the same command again refuses to start over them, another tune's options cannot resume them, and `--resume`
    tunes only what was left (pid-pf-ff from the journal's pid-pf-robust) and writes the file an uninterrupted run
    writes. The searches are stand-ins whose results depend only on what they are given."""
    import yaml

    from millvib_env.cli import main as cli_main
    from millvib_env.tuning import baselines, search as tuning

    calls: list[str] = []
    stop = {"at": "pid-pf-ff"}

    def tune(seeds, **k):
        calls.append("tune")
        shift = 0.1 if k.get("params") is not None else 0.0
        return tuning.TuneResult(np.array([5.5, 8.0, 2.0]) + shift + 1e-3 * len(seeds), 1.0 + 1e-2 * len(seeds),
                                 np.zeros(3), 2.0, 1)

    def tune_from(starts, seeds, **k):
        name = "pid-pf-ff" if starts.shape[1] == 5 else "pid-pf-robust"
        if name == stop["at"]:
            raise KeyboardInterrupt
        calls.append(name)
        return tuning.TuneResult(starts[0] + 0.25, 0.9 - 1e-2 * starts.shape[1], np.zeros(starts.shape[1]), 2.0, 1)

    monkeypatch.setattr(tuning, "tune", tune)
    monkeypatch.setattr(tuning, "tune_from", tune_from)
    monkeypatch.setattr(baselines, "_pf_starts", lambda t, seeds, version, pid: np.array([np.r_[pid, -4.0]]))
    only = ["--only", "pid-nominal", "pid-robust", "pid-pf-robust", "pid-pf-ff"]
    out, journal = tmp_path / "rolling.yaml", tmp_path / "rolling.yaml.partial"
    command = ["tune", "--task", "rolling", *only, "--out", str(out), "--quiet"]

    assert cli_main(command) == 130
    said = capsys.readouterr().err.strip().splitlines()
    assert len(said) == 1 and "interrupted; the finished entries (pid-nominal, pid-robust, pid-pf-robust)" in said[0]
    assert "--resume" in said[0] and not out.exists() and journal.is_file()
    kept = journal.read_bytes()

    assert cli_main(command) == 2
    assert "add --resume to go on from them" in capsys.readouterr().err and journal.read_bytes() == kept
    assert cli_main([*command, "--resume", "--grid", "3"]) == 2
    assert "journal of another tune (grid 5 there, 3 here)" in capsys.readouterr().err

    stop["at"], calls[:] = "", []
    assert cli_main([*command, "--resume"]) == 0
    assert calls == ["pid-pf-ff"] and not journal.exists()
    again = tmp_path / "again.yaml"
    assert cli_main(["tune", "--task", "rolling", *only, "--out", str(again), "--quiet"]) == 0
    resumed, whole = yaml.safe_load(out.read_text()), yaml.safe_load(again.read_text())
    assert resumed.pop("wall_time_s") >= 0 and whole.pop("wall_time_s") >= 0
    assert resumed == whole

    journal.write_text("run: {}\nwall_time_s: 1.0\nentries: 3\n")
    assert cli_main([*command, "--resume"]) == 2
    assert "is damaged" in capsys.readouterr().err
    journal.unlink()
    assert cli_main([*command, "--resume"]) == 2
    assert "there is no journal" in capsys.readouterr().err


def test_the_preview_feedforwards_search_is_the_same_in_one_process_and_in_two():
    """`tune_preview(processes=2)` (`millvib tune --jobs 2`) splits each batch of gain sets between two worker
    processes; every gain set's episodes are the same in any batch, so the search takes the same steps to the same
    gains, and the gains beat the reference alone on their plants."""
    from millvib_env.tasks import get_task
    from millvib_env.tuning.search import tune_preview

    t = get_task("startup")
    seeds = list(t.seeds["tuning"])[:2]
    one, two = (tune_preview(seeds, task=t, iters=2, processes=n) for n in (1, 2))
    assert one == two, (one, two)
    assert one["tuning_cost"] < one["reference_cost"] and one["n_evaluations"] >= 2 * 18
