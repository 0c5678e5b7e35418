"""Tune a task's baselines; write configs/control/<task>.yaml.

    python scripts/tune_pid.py --task rolling              # every baseline of the task
    python scripts/tune_pid.py --task startup --only lqr-oracle pid-adaptive

All on the task's tuning seeds (configs/tasks.yaml), disjoint from its held-out seeds:
* pid-nominal: the nominal plant only (Table 1 c1 and Ct), the way a PID is commissioned, over
  8 episodes of disturbances (tuning seeds +0..7);
* pid-robust: one set of gains for the whole task distribution: 32 plants drawn by the
  environment (tuning seeds +100..131);
* pid-oracle: a 5 x 5 grid over (log c1, log Ct), gains tuned per grid plant over 6 episodes of
  disturbances (tuning seeds +200..205); the policy interpolates log gains between grid points;
* lqr-oracle: the LQR weights (a grid over q_v, q_p, q_i, r and the friction linearisation, then
  Nelder-Mead) minimising the mean cost of per-plant LQR designs over the pid-robust plants;
* pid-adaptive: the estimator's forgetting time constant, over the pid-robust plants.

pid-nominal, pid-robust and pid-oracle are grid searches over log10 (KP, KI, KD) followed by
Nelder-Mead (millvib_env.training.tuning). With --optuna STORAGE, pid-nominal and pid-robust are
tuned by an Optuna study instead (TPE), whose storage several machines share: run the same command
on each, e.g.

    python scripts/tune_pid.py --task rolling --only pid-robust --optuna journal:/shared/tune.log --trials 100
    python scripts/tune_pid.py --task rolling --only pid-robust --optuna postgresql://user@db/tuning --trials 100

and the last to finish writes the study's best gains (each run writes the best so far). A task may take an entry from another task (`--from
rolling` for `change`: the oracle's per-plant table and the LQR weights are properties of plants,
not of the episode).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import yaml
from tqdm.auto import tqdm

from millvib_env._paths import config_dir, write_text_atomic
from millvib_env._yaml import load_yaml
from millvib_env.tasks import get_task, list_tasks
from millvib_env.training.tuning import tune, tune_adaptive, tune_lqr, tune_optuna

ENTRIES = ("pid-nominal", "pid-robust", "pid-oracle", "lqr-oracle", "pid-adaptive")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--task", default="startup", choices=list_tasks())
    ap.add_argument("--only", nargs="+", choices=ENTRIES, help="tune only these entries (keep the others)")
    ap.add_argument("--from", dest="from_task", choices=list_tasks(),
                    help="take pid-oracle and lqr-oracle from this task instead of tuning them")
    ap.add_argument("--grid", type=int, default=5, help="oracle grid points per axis (default 5)")
    ap.add_argument("--optuna", metavar="STORAGE", help="tune pid-nominal and pid-robust by an Optuna study in "
                                                        "STORAGE (journal:PATH or a database URL), shared by "
                                                        "every process that names it")
    ap.add_argument("--trials", type=int, default=60, help="Optuna trials this process runs (default 60)")
    args = ap.parse_args()
    task = get_task(args.task)
    first = task.seeds["tuning"].start
    nominal_seeds = list(range(first, first + 8))
    robust_seeds = list(range(first + 100, first + 132))
    oracle_seeds = list(range(first + 200, first + 206))
    path = config_dir() / "control" / f"{task.name}.yaml"
    out: dict = load_yaml(path) if path.exists() else {}
    out.setdefault("cost", "mean episode cost = severity / 4.5 mm/s + tracking RMS / 10 um, gain-schedule env "
                           f"config {task.config}, gains held fixed")
    out.setdefault("search", "grid over log10 KP in 4..7 (step 0.25), KI in {-3, 2, 4..8}, KD in {0, 1, 1.5, 2, "
                             "log10 300}, then Nelder-Mead (60 iterations) from the best grid point")
    todo = args.only or list(ENTRIES)
    start = time.time()
    if args.optuna:
        for name, seeds, pinned in (("pid-nominal", nominal_seeds, {"c1": 2.25e6, "Ct": 5e-16}),
                                    ("pid-robust", robust_seeds, None)):
            if name in todo:
                print(f"tuning {name} with Optuna ({args.optuna}) ...", flush=True)
                res = tune_optuna(seeds, task=task.name, storage=args.optuna, study_name=f"{task.name}-{name}",
                                  n_trials=args.trials, params=pinned)
                out[name] = {**res, "seeds": [seeds[0], seeds[-1]],
                             "how": f"Optuna TPE study {task.name}-{name} over log10 gains ({res['n_trials']} trials)"}
                print(f"  {res}", flush=True)
                todo = [t for t in todo if t != name]
    if "pid-nominal" in todo:
        print("tuning pid-nominal on the nominal plant ...", flush=True)
        res = tune(nominal_seeds, task=task.name, params={"c1": 2.25e6, "Ct": 5e-16})
        out["pid-nominal"] = {"gains": res.gains, "log10_gains": [round(float(v), 4) for v in res.log10_gains],
                              "tuning_cost": round(res.cost, 4), "seeds": [nominal_seeds[0], nominal_seeds[-1]],
                              "how": "tuned on the nominal plant only (c1 = 2.25e6, Ct = 5e-16), 8 disturbance draws"}
        print(f"  {res.gains} cost {res.cost:.3f}", flush=True)
    if "pid-robust" in todo:
        print("tuning pid-robust over 32 tuning plants ...", flush=True)
        res = tune(robust_seeds, task=task.name)
        out["pid-robust"] = {"gains": res.gains, "log10_gains": [round(float(v), 4) for v in res.log10_gains],
                             "tuning_cost": round(res.cost, 4), "seeds": [robust_seeds[0], robust_seeds[-1]],
                             "how": "one set of gains minimising the mean cost over 32 plants of the task"}
        print(f"  {res.gains} cost {res.cost:.3f}", flush=True)
    if args.from_task:
        for name in ("pid-oracle", "lqr-oracle"):
            if name in todo:
                out[name] = {"from_task": get_task(args.from_task).name}
    if "pid-oracle" in todo and not args.from_task:
        c1_grid = np.geomspace(1.25e5, 2.25e6, args.grid)
        ct_grid = np.geomspace(5e-16, 5e-9, args.grid)
        log_gains = np.zeros((args.grid, args.grid, 3))
        costs = np.zeros((args.grid, args.grid))
        cells = [(i, j) for i in range(args.grid) for j in range(args.grid)]
        for i, j in tqdm(cells, desc="tuning pid-oracle grid", unit="plant"):
            res = tune(oracle_seeds, task=task.name, params={"c1": float(c1_grid[i]), "Ct": float(ct_grid[j])},
                       refine_iters=40)
            log_gains[i, j] = res.log10_gains
            costs[i, j] = res.cost
        out["pid-oracle"] = {"c1_grid": [float(v) for v in c1_grid], "ct_grid": [float(v) for v in ct_grid],
                             "log10_gains": np.round(log_gains, 4).tolist(),
                             "tuning_costs": np.round(costs, 4).tolist(),
                             "seeds": [oracle_seeds[0], oracle_seeds[-1]],
                             "how": "gains tuned per grid plant over 6 disturbance draws; log10 gains interpolated "
                                    "bilinearly in (log c1, log Ct) between grid points"}
    if "lqr-oracle" in todo and not args.from_task:
        print("tuning lqr-oracle weights ...", flush=True)
        res = tune_lqr(robust_seeds, task=task.name)
        out["lqr-oracle"] = {**res, "seeds": [robust_seeds[0], robust_seeds[-1]],
                             "how": "LQR weights (grid, then Nelder-Mead) minimising the mean cost of per-plant "
                                    "designs over 32 tuning plants"}
        print(f"  {res}", flush=True)
    if "pid-adaptive" in todo:
        _write(path, out, start)  # the estimator uses this task's oracle table
        print("tuning pid-adaptive forgetting time ...", flush=True)
        res = tune_adaptive(robust_seeds, task=task.name)
        out["pid-adaptive"] = {**res, "seeds": [robust_seeds[0], robust_seeds[-1]],
                               "how": "estimator forgetting time constant with the lowest mean cost over 32 "
                                      "tuning plants; gains from the pid-oracle table at the estimate"}
        print(f"  {res}", flush=True)
    _write(path, out, start)


def _write(path, out: dict, start: float) -> None:
    out["wall_time_s"] = round(time.time() - start, 1)
    header = "# Written by scripts/tune_pid.py; see its docstring for the method.\n"
    write_text_atomic(path, header + yaml.safe_dump(out, sort_keys=False, width=110))
    print(f"wrote {path} ({out['wall_time_s']} s)", flush=True)


if __name__ == "__main__":
    main()
