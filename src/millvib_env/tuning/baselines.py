"""`millvib tune`: a task's classical baselines tuned on its tuning seeds, written where the user says.

All on the task's tuning seeds (configs/tasks.yaml), disjoint from its validation and held-out seeds:

* ``pid-nominal``: the nominal plant only (Table 1 c1 and Ct), the way a PID is commissioned, over
  8 episodes of disturbances (tuning seeds +0..7);
* ``pid-robust``: one PID for the whole task distribution: 32 plants drawn by the environment
  (tuning seeds +100..131);
* ``pid-oracle``: a 5 x 5 grid over (log c1, log Ct), gains tuned per grid plant over 6 episodes of
  disturbances (tuning seeds +200..205); the policy interpolates log gains between grid points;
* ``lqr-oracle``: the LQR weights (a grid over q_v, q_p, q_i, r and the friction linearisation, then
  Nelder-Mead) minimising the mean cost of per-plant LQR designs over the pid-robust plants;
* ``pid-adaptive``: the estimator's forgetting time constant, over the pid-robust plants;
* ``pid-pf-robust``: one PID + pressure feedback (KP, KI, KD, KPL) for the whole distribution, on
  the pid-robust plants: a coarse grid (and the LQR design of the centre plant) then Nelder-Mead;
* ``pid-pf-ff``: pid-pf-robust plus a feedforward of the load cells' force deviation (KFF), all
  five gains refined together from pid-pf-robust with KFF on a grid around KPL / Ap;
* ``pid-pf-oracle``: a per-plant table of PID + pressure-feedback gains on the pid-oracle grid,
  each refined from pid-pf-robust over 32 disturbance draws (tuning seeds +200..231).

The result goes to ``--out FILE`` (the task's shipped control config with the tuned entries replaced,
so it can be read back), or with ``--write-config`` into configs/control/<task>.yaml. Either way an
entry that costs more on its tuning plants than the entry it would replace is kept out and reported,
unless ``--force`` (a 2-trial Optuna study never replaces a better shipped baseline silently). A run
of some entries (``--only``) keeps the file's ``wall_time_s``, the whole tune's, and prints its own.

Each finished entry is written at once to a journal beside the result (``FILE.partial``): a run that a Ctrl-C, a
crash or a lost machine ends says so, and the same command with ``--resume`` goes on from its finished entries
to the file an uninterrupted run writes (``tuning.journal``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from millvib_env._checks import integer, shown
from millvib_env._paths import check_output, write_text_atomic
from millvib_env._yaml import load_yaml
from millvib_env.control.base import GainTable
from millvib_env.catalog.factory import control_config_path, control_entry, oracle_table
from millvib_env.catalog.registry import LOOP_ONLY
from millvib_env.catalog.tuned import shared_from
from millvib_env.control.lqr import LQRWeights, lqr_gains
from millvib_env.distributed import run_jobs
from millvib_env.envs.config import cached_env_config
from millvib_env.params import MillParams
from millvib_env.tasks import Task, takes_task
from millvib_env.tuning import ENTRIES  # every entry `millvib tune` tunes, in TUNERS' order
from millvib_env.tuning import search as tuning  # the searches, called through the module (a test stands them in)
from millvib_env.tuning.journal import open_journal
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["ENTRIES", "tune_task", "merge_entries", "tune_from_cli", "tuning_seeds"]

#: the plant of pid-nominal: Table 1's c1 and Ct (`MillParams`' defaults, their one home)
NOMINAL_PLANT = {"c1": MillParams().c1, "Ct": MillParams().Ct}
#: pid-pf-oracle's "how"
PF_ORACLE_HOW = ("PID + pressure-feedback gains tuned per grid plant over 32 disturbance draws (Nelder-Mead from "
                 "pid-pf-robust, 60 iterations, never worse than pid-pf-robust on them); log10 gains interpolated "
                 "bilinearly in (log c1, log Ct). With 6 draws per plant (as pid-oracle) the table overfitted: "
                 "1.083 on the rolling validation plants against 0.993 for pid-pf-robust")


def tuning_seeds(task: Task) -> dict[str, list[int]]:
    """The tuning seeds of each kind of entry (offsets into the task's tuning range)."""
    first = task.seeds["tuning"].start
    return {"nominal": list(range(first, first + 8)), "robust": list(range(first + 100, first + 132)),
            "oracle": list(range(first + 200, first + 206)), "pf-oracle": list(range(first + 200, first + 232))}


def _gain_entry(res, seeds: list[int], how: str) -> dict:
    return {"gains": res.gains, "log10_gains": [round(float(v), 4) for v in res.log10_gains],
            "tuning_cost": round(res.cost, 4), "seeds": [seeds[0], seeds[-1]], "how": how}


def _pf_starts(task: Task, seeds: list[int], version: str = DEFAULT_VERSION,
               pid: list[float] | None = None) -> np.ndarray:
    """Starting points of the PID + pressure-feedback search: a coarse grid over (KP, KI, KPL) with KD
    at its 300 V s/m limit, the LQR design of the task's centre plant, and (where given) the tuned PID
    `pid` (log10 KP, KI, KD) with the weakest pressure feedback, so the search never ends above the PID
    it extends."""

    grid = np.stack(np.meshgrid([5.5, 6.0, 6.5], [7.0, 8.0, 9.0], [np.log10(300.0)], [-5.0, -4.5, -4.0, -3.5],
                                indexing="ij"), axis=-1).reshape(-1, 4)
    cfg = task.configs[version]
    centre = {d.name: math.sqrt(d.low * d.high) for d in cfg.randomize if d.name in ("c1", "Ct")}
    starts = [grid]
    try:
        weights = LQRWeights(**control_entry(task, "lqr-oracle", version)["weights"])
    except (ValueError, KeyError, TypeError):
        weights = LQRWeights()
    try:
        g = lqr_gains(cfg.base_params.replace(**centre), weights, dt_s=None if cfg.loop is None else cfg.loop.dt_s)
        if np.all(np.isfinite(g)) and np.all(g > 0):
            starts.append(np.log10(np.minimum(g, [1e7, 1e10, 300.0, 1e-2]))[None, :])
    except (np.linalg.LinAlgError, ValueError):
        pass
    if pid is not None:

        starts.append(np.r_[np.asarray(pid, float)[:3], math.log10(tuning.PF_BOUNDS["kpl"][0])][None, :])
    return np.concatenate(starts)


def _tune_with_optuna(t: Task, seeds: dict, todo: list[str], storage: str, trials: int, say,
                      version: str = DEFAULT_VERSION) -> dict[str, Any]:
    """pid-nominal and pid-robust (those in `todo`) tuned by Optuna studies in `storage`."""

    out: dict[str, Any] = {}
    for name, s, pinned in (("pid-nominal", seeds["nominal"], NOMINAL_PLANT), ("pid-robust", seeds["robust"], None)):
        if name in todo:
            say(f"tuning {name} with Optuna ({storage}) ...")
            res = tuning.tune_optuna(s, task=t, storage=storage, study_name=f"{t.name}-{name}", n_trials=trials,
                              params=pinned, version=version)
            out[name] = {**res, "seeds": [s[0], s[-1]],
                         "how": f"Optuna TPE study {t.name}-{name} over log10 gains ({res['n_trials']} trials)"}
    return out


def _bar_name(progress: bool, name: str) -> str | None:
    """The name of a tuner's progress bar over its evaluations (None: no bar)."""
    return f"tuning {name}" if progress else None


@dataclass
class _Run:
    """One `tune_task` call: the task, its tuning seeds and what this run has tuned so far (`out`)."""

    t: Task
    seeds: dict[str, list[int]]
    version: str
    grid: int
    progress: bool
    shipped: dict
    out: dict = field(default_factory=dict)
    jobs: int = 1

    def say(self, msg: str) -> None:
        if self.progress:
            print(msg, flush=True)

    def current(self, name: str) -> dict:
        """Entry `name` from this run, else from the shipped config (an entry another builds on)."""
        entry = self.out.get(name, self.shipped.get(name))
        if entry is None:
            raise ValueError(f"tuning needs the {shown(name)} entry of task {shown(self.t.name)}: tune it in the "
                             f"same run (--only {name} ...)")
        return entry

    def bar(self, name: str) -> str | None:
        return _bar_name(self.progress, name)


def _tune_nominal(r: _Run) -> dict:

    r.say("tuning pid-nominal on the nominal plant ...")
    res = tuning.tune(r.seeds["nominal"], task=r.t, params=NOMINAL_PLANT, version=r.version,
               progress=r.bar("pid-nominal"))
    return _gain_entry(res, r.seeds["nominal"], "tuned on the nominal plant only (c1 = 2.25e6, Ct = 5e-16), 8 "
                                                "disturbance draws")


def _tune_robust(r: _Run) -> dict:

    r.say("tuning pid-robust over 32 tuning plants ...")
    res = tuning.tune(r.seeds["robust"], task=r.t, version=r.version, progress=r.bar("pid-robust"))
    return _gain_entry(res, r.seeds["robust"], "one set of gains minimising the mean cost over 32 plants of the task")


def _tune_pid_oracle(r: _Run) -> dict:

    return _tuned_table(r, "pid-oracle", r.seeds["oracle"], (
        "gains tuned per grid plant over 6 disturbance draws; log10 gains interpolated bilinearly in "
        "(log c1, log Ct) between grid points"))


def _tune_lqr(r: _Run) -> dict:

    r.say("tuning lqr-oracle weights ...")
    res = tuning.tune_lqr(r.seeds["robust"], task=r.t, version=r.version)
    return {**res, "seeds": [r.seeds["robust"][0], r.seeds["robust"][-1]],
            "how": "LQR weights (grid, then Nelder-Mead) minimising the mean cost of per-plant designs over 32 "
                   "tuning plants"}


def _tune_adaptive(r: _Run) -> dict:

    r.say("tuning pid-adaptive forgetting time ...")
    res = tuning.tune_adaptive(r.seeds["robust"], task=r.t, table=_table(r.current("pid-oracle"), r.version),
                        version=r.version)
    return {**res, "seeds": [r.seeds["robust"][0], r.seeds["robust"][-1]],
            "how": "estimator forgetting time constant with the lowest mean cost over 32 tuning plants; gains "
                   "from the pid-oracle table at the estimate"}


def _refined(r: _Run, name: str, starts: np.ndarray, iters: int, how: str) -> dict:
    """A fixed-gain entry refined by Nelder-Mead from `starts` over the pid-robust plants; says its gains."""

    res = tuning.tune_from(starts, r.seeds["robust"], task=r.t, refine_iters=iters, version=r.version,
                    progress=r.bar(name))
    entry = _gain_entry(res, r.seeds["robust"], how)
    r.say(f"  {entry['gains']} cost {res.cost:.4f}")
    return entry


def _tune_pf_robust(r: _Run) -> dict:
    r.say("tuning pid-pf-robust (PID + pressure feedback) over 32 tuning plants ...")
    pid = (r.out.get("pid-robust") or r.shipped.get("pid-robust") or {}).get("log10_gains")
    return _refined(r, "pid-pf-robust", _pf_starts(r.t, r.seeds["robust"], r.version, pid), 200, (
        "one PID + pressure feedback (KP, KI, KD, KPL) minimising the mean cost over the 32 pid-robust plants: "
        "the best of a 36-point grid (KP 10^5.5-10^6.5, KI 10^7-10^9, KD 300, KPL 10^-5-10^-3.5), the LQR "
        "design of the centre plant and pid-robust with KPL = 1e-8, refined by Nelder-Mead (200 iterations, "
        "KD <= 300)"))


def _tune_pf_ff(r: _Run) -> dict:
    r.say("tuning pid-pf-ff (pid-pf-robust + force feedforward) over 32 tuning plants ...")
    base = np.asarray(r.current("pid-pf-robust")["log10_gains"], float)
    kff = np.log10(10.0 ** base[3] / _area(r.t) * np.array([0.25, 0.5, 0.75, 1.0, 1.25]))
    return _refined(r, "pid-pf-ff", np.array([np.r_[base, k] for k in kff]), 250, (
        "pid-pf-robust plus KFF (u += KFF (FL(t) - FL), the load cells' force deviation): KFF on a grid of "
        "0.25-1.25 x KPL / Ap from pid-pf-robust's gains, then all five gains refined by Nelder-Mead "
        "(250 iterations, KD <= 300) over the 32 pid-robust plants"))


def _tune_preview(r: _Run) -> dict:
    if r.version == "v0":
        raise ValueError("pid-pf-preview runs on the loop as commissioned: tune it with --env-version v1")
    r.say("tuning pid-pf-preview (pid-pf-robust + the preview's feedforward, 17 gains) over 32 tuning plants ...")
    res = tuning.tune_preview(r.seeds["robust"], task=r.t, progress=r.bar("pid-pf-preview"), processes=r.jobs)
    r.say(f"  cost {res['tuning_cost']:.4f} (pid-pf-robust alone {res['reference_cost']:.4f})")
    base = r.current("pid-pf-robust").get("from_task") or r.t.name
    return {**res, "gauge": tuning.PREVIEW_TUNING_GAUGE, "seeds": [r.seeds["robust"][0], r.seeds["robust"][-1]],
            "how": (f"the preview feedforward's 17 gains on pid-pf-robust ({base}'s), minimising the mean cost over "
                    "the 32 pid-robust plants with the preview measured (envs.gauge defaults): L-BFGS-B from zero "
                    f"with forward-difference gradients ({res['n_evaluations']} gain sets evaluated)")}


def _tune_pf_oracle(r: _Run) -> dict:

    base = [float(v) for v in r.current("pid-pf-robust")["log10_gains"]]
    return _tuned_table(r, "pid-pf-oracle", r.seeds["pf-oracle"], PF_ORACLE_HOW, base=base)


def _tune_cell(kind: str, task: Task, seeds: list[int], plant: dict, version: str,
               base: list[float] | None = None) -> tuning.TuneResult:
    """One grid plant of an oracle table (`kind` pid-oracle or pid-pf-oracle): a job of its own, so that
    `--jobs N` tunes the plants in N worker processes (each plant is independent: the same gains)."""
    return _CELL_TUNERS[kind](task, seeds, plant, version, base)


def _pid_cell(task: Task, seeds: list[int], plant: dict, version: str, base: list[float] | None):
    """A pid-oracle cell: the PID's grid search and Nelder-Mead on the plant."""
    return tuning.tune(seeds, task=task, params=plant, refine_iters=40, version=version)


def _pf_cell(task: Task, seeds: list[int], plant: dict, version: str, base: list[float] | None):
    """A pid-pf-oracle cell: Nelder-Mead from pid-pf-robust's gains (`base`) on the plant."""
    return tuning.tune_from(np.asarray(base, float)[None, :], seeds, task=task, refine_iters=60, step_decades=0.2,
                            params=plant, version=version)


#: how one grid plant of each oracle table is tuned
_CELL_TUNERS: dict[str, Callable[..., tuning.TuneResult]] = {"pid-oracle": _pid_cell, "pid-pf-oracle": _pf_cell}


#: how each tunable baseline is tuned, in the order a run tunes them (an entry may build on one before it)
TUNERS: dict[str, Callable[[_Run], dict]] = {
    "pid-nominal": _tune_nominal, "pid-robust": _tune_robust, "pid-oracle": _tune_pid_oracle, "lqr-oracle": _tune_lqr,
    "pid-adaptive": _tune_adaptive, "pid-pf-robust": _tune_pf_robust, "pid-pf-ff": _tune_pf_ff,
    "pid-pf-oracle": _tune_pf_oracle, "pid-pf-preview": _tune_preview,
}
#: the entries that `--from-task` shares with another task instead of tuning them (the oracles' tables)
SHARED = ("pid-oracle", "lqr-oracle", "pid-pf-oracle")


@takes_task("task", "from_task")
def tune_task(task: str | Task, only: list[str] | None = None, *, from_task: str | Task | None = None, grid: int = 5,
              optuna: str | None = None, trials: int = 60, shipped: dict | None = None,
              progress: bool = True, version: str = DEFAULT_VERSION, jobs: int = 1, done: dict | None = None,
              on_entry: Callable[[str, dict], None] | None = None) -> dict[str, Any]:
    """Tune the entries `only` (default: every entry) of `task`; returns {entry: its config}. Entries
    that build on another (pid-pf-ff on pid-pf-robust, pid-adaptive on pid-oracle) take it from this
    run or else from `shipped` (the task's control config). `jobs`: worker processes for the oracle tables'
    grid plants and pid-pf-preview's batches of gain sets (`distributed.run_jobs`; the same results for any
    number). `done`: entries an earlier, unfinished
    run of the same call tuned (`tuning.journal`), taken as this run's and not tuned again; `on_entry(name, entry)`
    is called as each entry is finished (the journal is written there)."""
    jobs = integer("jobs", jobs, lo=1, hi=1024)
    assert isinstance(task, Task) and (from_task is None or isinstance(from_task, Task))  # by @takes_task
    t = task
    shared_from = None if from_task is None else from_task.name
    r = _Run(t, tuning_seeds(t), version, grid, progress, dict(shipped or {}), jobs=jobs)
    todo = list(dict.fromkeys(only or [n for n in ENTRIES if version != "v0" or n not in LOOP_ONLY]))
    r.out.update({name: entry for name, entry in (done or {}).items() if name in todo})
    if r.out:
        r.say(f"resumed: {', '.join(r.out)} from the unfinished run")
    finished = on_entry or (lambda name, entry: None)
    if optuna and any(name not in r.out for name in todo):
        by_study = _tune_with_optuna(t, r.seeds, [n for n in todo if n not in r.out], optuna, trials, r.say, version)
        for name, entry in by_study.items():
            r.out[name] = entry
            finished(name, entry)
    for name, step in TUNERS.items():
        if name not in todo or name in r.out:
            continue
        r.out[name] = {"from_task": shared_from} if shared_from and name in SHARED else step(r)
        finished(name, r.out[name])
    return {name: r.out[name] for name in TUNERS if name in r.out}


def _tuned_table(r: _Run, name: str, seeds: list[int], how: str, base: list[float] | None = None) -> dict:
    """A per-plant gain table on the oracle grid: `_tune_cell` (a TuneResult) for each grid plant, in this process
    or in `r.jobs` worker processes."""
    from tqdm.auto import tqdm

    grid = r.grid
    c1_grid, ct_grid, cells = _oracle_grid(r.t, grid, r.version)
    jobs = [{"kind": name, "task": r.t, "seeds": seeds, "plant": {"c1": float(c1_grid[i]), "Ct": float(ct_grid[j])},
             "version": r.version, "base": base} for i, j in cells]
    if r.jobs > 1:
        done = run_jobs(_tune_cell, jobs, processes=r.jobs, progress=r.progress,
                        desc=f"tuning {name} grid ({r.jobs} processes)")
    else:
        done = [_tune_cell(**job) for job in tqdm(jobs, desc=f"tuning {name} grid", unit="plant",
                                                  disable=not r.progress)]
    results = dict(zip(cells, done))
    log_gains = np.array([[results[i, j].log10_gains for j in range(grid)] for i in range(grid)])
    costs = np.array([[results[i, j].cost for j in range(grid)] for i in range(grid)])
    return _table_entry(c1_grid, ct_grid, log_gains, costs, seeds, how)


def _area(t: Task) -> float:
    return float(t.configs["v0"].base_params.Ap)


def _oracle_grid(t: Task, n: int, version: str = DEFAULT_VERSION):
    """The oracle tables' grid: n x n over the (log c1, log Ct) ranges of the startup task's draw in the
    version, whatever the task: a table is a property of plants, and the `change` task's plants move
    over the whole range."""
    dists = {d.name: d for d in cached_env_config("startup", version).randomize}
    c1_grid = np.geomspace(dists["c1"].low, dists["c1"].high, n)
    ct_grid = np.geomspace(dists["Ct"].low, dists["Ct"].high, n)
    return c1_grid, ct_grid, [(i, j) for i in range(n) for j in range(n)]


def _table_entry(c1_grid, ct_grid, log_gains, costs, seeds, how: str) -> dict:
    return {"c1_grid": [float(v) for v in c1_grid], "ct_grid": [float(v) for v in ct_grid],
            "log10_gains": np.round(log_gains, 4).tolist(), "tuning_costs": np.round(costs, 4).tolist(),
            "seeds": [seeds[0], seeds[-1]], "how": how}


def _table(entry: dict, version: str = DEFAULT_VERSION):

    source = shared_from(entry, "pid-oracle")
    if source is not None:
        return oracle_table(source, version=version)
    return GainTable(entry["c1_grid"], entry["ct_grid"], np.array(entry["log10_gains"]))


def _cost(entry: dict | None) -> float | None:
    """An entry's tuning cost (a table's: its mean over the grid; pid-adaptive's: that of the forgetting time it
    took, the lowest of its candidates'), None where it has none."""
    if not isinstance(entry, dict):
        return None
    if "tuning_cost" in entry:
        return float(entry["tuning_cost"])
    costs = entry.get("tuning_costs")
    if isinstance(costs, list):
        return float(np.mean(costs))
    if isinstance(costs, dict) and costs:
        return float(min(costs.values()))
    return None


def merge_entries(shipped: dict, tuned: dict, *, force: bool = False) -> tuple[dict, list[str]]:
    """`shipped` with the `tuned` entries in; an entry dearer on its tuning plants than the one it
    would replace is kept out unless `force`. Returns the merged config and a line per decision."""
    merged, notes = dict(shipped), []
    for name, entry in tuned.items():
        old, new = _cost(shipped.get(name)), _cost(entry)
        if old is not None and new is not None and new > old and not force:
            notes.append(f"{name}: kept the existing entry (tuning cost {old:.4g}); this run's {new:.4g} is worse "
                         "(--force replaces it)")
            continue
        merged[name] = entry
        if old is not None:
            said = f"replaces {old:.4g} with"
        else:
            said = "replaces the existing entry (no tuning cost to compare)" if name in shipped else "new"
        notes.append(f"{name}: {said} {'' if new is None else f'{new:.4g}'}".rstrip())
    return merged, notes


def tune_from_cli(args) -> int:
    import yaml

    t = args.task  # resolved by the CLI
    if bool(args.out) == bool(args.write_config):
        raise ValueError("say where the result goes: --out FILE (a copy of the task's control config with the "
                         "tuned entries) or --write-config (configs/control/<task>.yaml itself), not both")
    if args.trials < 1:
        raise ValueError(f"--trials {args.trials} is invalid: a whole number >= 1")
    if not 2 <= args.grid <= 12:
        raise ValueError(f"--grid {args.grid} is invalid: 2-12 points per axis")

    version = args.env_version
    shipped_path = control_config_path(t, version)
    target = shipped_path if args.write_config else Path(args.out)
    check_output(str(target), "--out")
    shipped = load_yaml(shipped_path, "control config") if shipped_path.is_file() else {}
    if not isinstance(shipped, dict):
        raise ValueError(f"{shipped_path} must be a mapping of entries")
    run = {"task": t.name, "env_version": version, "only": None if not args.only else list(dict.fromkeys(args.only)),
           "grid": args.grid, "from_task": getattr(args.from_task, "name", args.from_task),
           "optuna": args.optuna, "trials": args.trials if args.optuna else None}
    journal = open_journal(target, run, args.resume)
    start = time.time()
    clock = [start]

    def finished(name: str, entry: dict) -> None:
        now = time.time()
        journal.record(name, entry, now - clock[0])
        clock[0] = now

    tuned = tune_task(t, args.only, from_task=args.from_task, grid=args.grid, optuna=args.optuna,
                      trials=args.trials, shipped=shipped, progress=not args.quiet, version=version, jobs=args.jobs,
                      done=journal.entries, on_entry=finished)
    merged, notes = merge_entries(shipped, tuned, force=args.force)
    merged.setdefault("cost", "mean episode cost = severity / 4.5 mm/s + tracking RMS / 10 um (a diverged episode: at "
                              f"least 1000), gain-schedule env {version} config {t.config}, gains held fixed")
    took = round(journal.wall_time_s + time.time() - clock[0], 1)  # an unfinished run's seconds and this one's
    if not args.only or "wall_time_s" not in merged:  # a run of some entries leaves the whole tune's time as it was
        merged["wall_time_s"] = took
    header = (f"# Written by `millvib tune --task {t.name} --env-version {version}` (millvib_env.tuning.baselines: "
              "the method of each entry is in its `how`).\n")
    write_text_atomic(target, header + yaml.safe_dump(merged, sort_keys=False, width=110))
    journal.close()
    for line in notes:
        print(line)
    print(f"wrote {target} ({took} s)")
    return 0
