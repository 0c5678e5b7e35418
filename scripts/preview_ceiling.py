"""The ceiling of the classical preview controller under any schedule of its gains, an adaptive one included:
`pid-pf-preview`'s 17 feedforward gains re-tuned for each held-out plant on that plant's own episode
(`tuning.search.tune_preview_per_plant`), against the shipped `pid-pf-preview`, its students and `mpc-preview`
on the same plants, from the task's saved benchmark (rerun `millvib benchmark --task T --all-seeds --out
docs/benchmark/v1/T` first).

    MILLVIB_NUM_THREADS=1 python scripts/preview_ceiling.py --task varied --jobs 2 \
        > docs/benchmark/v1/varied/preview-ceiling.md

The re-tuned controller knows the plant and the very disturbances and gauge errors it is scored on, so no
schedule of these gains (fixed per episode) does better on that plant; an adaptive one estimating the plant
online costs more. Its per-plant gains and costs are written beside the benchmark (preview-ceiling.json).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FF = "pid-pf-preview"
BOUND = "mpc-preview"


def _tune(task: str, seeds: list[int], start: list[float], progress: str | None) -> dict:
    from millvib_env.tasks import get_task
    from millvib_env.tuning.search import tune_preview_per_plant

    return tune_preview_per_plant(seeds, task=get_task(task), start=start, progress=progress)


def _episodes(folder: Path) -> dict:
    cost: dict = defaultdict(dict)
    with open(folder / "episodes.csv") as fh:
        for r in csv.DictReader(fh):
            cost[r["controller"]][(r["agent_seed"], int(r["seed"]))] = float(r["cost"])
    return cost


def _pct(d: dict, key: str = "cost_diff_rel", ci: str = "ci") -> str:
    lo, hi = d[ci]
    return f"{d[key]:+.1%} [{lo:+.1%}, {hi:+.1%}]"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="varied", choices=("startup", "rolling", "change", "varied"))
    ap.add_argument("--jobs", type=int, default=2, help="processes (the plants split between them)")
    ap.add_argument("--plants", type=int, default=None, help="the first N of the benchmark's plants (default: all)")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs = {args.jobs} is invalid: at least 1")

    import yaml

    from millvib_env._paths import write_text_atomic
    from millvib_env.evaluation.stats import cvar, paired_difference

    folder = ROOT / "docs" / "benchmark" / "v1" / args.task
    result = json.loads((folder / "benchmark.json").read_text())
    cost = _episodes(folder)
    seeds = sorted(p for _, p in cost[FF])[: args.plants]
    start = yaml.safe_load((ROOT / "configs" / "control" / "v1" / f"{args.task}.yaml").read_text())[FF]["gains"]
    parts = [seeds[k::args.jobs] for k in range(args.jobs)]
    with ProcessPoolExecutor(args.jobs) as pool:
        outs = list(pool.map(_tune, [args.task] * args.jobs, parts, [start] * args.jobs,
                             ["per-plant tuning"] + [None] * (args.jobs - 1)))
    tuned = {s: (c, c0, g) for o in outs for s, c, c0, g in zip(o["seeds"], o["cost"], o["start_cost"], o["gains"])}
    ff = np.array([cost[FF][("", s)] for s in seeds])
    start_gap = max(abs(tuned[s][1] / f - 1.0) for s, f in zip(seeds, ff))
    if start_gap > 1e-9:
        raise SystemExit(f"the search's start costs {start_gap:.2e} apart from the benchmark's {FF} episodes: "
                         "the saved benchmark is not of these gains; rerun it")
    ceiling = np.array([tuned[s][0] for s in seeds])
    bound = np.array([cost[BOUND][("", s)] for s in seeds])
    learned = [n for n, c in result["controllers"].items() if c.get("same_information", {}).get("classical") == FF]
    write_text_atomic(folder / "preview-ceiling.json", json.dumps(
        {"task": args.task, "plants": seeds, "cost": ceiling.tolist(), FF: ff.tolist(),
         "gains": [tuned[s][2] for s in seeds]}, indent=1) + "\n")

    print(f"# {args.task}: the classical preview controller re-tuned per plant\n")
    print(f"`MILLVIB_NUM_THREADS=1 python scripts/preview_ceiling.py --task {args.task} --jobs {args.jobs}`, on the "
          f"saved benchmark's {len(seeds)} held-out plants (measured preview). `{FF}` re-tuned per plant: its 17 "
          "gains fitted to each plant's own episode (the plant, its disturbances and its gauge errors known), "
          "a ceiling for any schedule of the gains, an adaptive one included. Paired 95 % intervals.\n")
    room = ff.mean() - bound.mean()
    print("| controller | cost mean | CVaR-20 | vs pid-pf-preview | vs the re-tuned: mean | CVaR-20 | "
          "share of the room |")
    print("|---|---|---|---|---|---|---|")

    def row(name: str, per_seed: list[np.ndarray]) -> None:
        m = float(np.mean(per_seed))
        vs_ff = paired_difference(per_seed, ff)
        vs_ceiling = paired_difference(per_seed, ceiling)
        print(f"| {name} | {m:.3f} | {float(cvar(np.concatenate(per_seed))):.3f} | {_pct(vs_ff)} | "
              f"{_pct(vs_ceiling)} | {_pct(vs_ceiling, 'cvar20_diff_rel', 'cvar20_ci')} | "
              f"{(ff.mean() - m) / room:.0%} |")

    row(f"{FF} (shipped)", [ff])
    row(f"{FF} re-tuned per plant", [ceiling])
    for name in learned:
        agent_seeds = sorted({a for a, _ in cost[name]})
        row(name, [np.array([cost[name][(a, s)] for s in seeds]) for a in agent_seeds])
    row(f"{BOUND} (bound)", [bound])
    return 0


if __name__ == "__main__":
    sys.exit(main())
