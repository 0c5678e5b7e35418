"""Two controllers paired on a task's validation plants that no selection used (a check before anything ships).

    MILLVIB_NUM_THREADS=1 python scripts/validation_pairs.py agents/dagger-on-pid-pf-preview-rolling/seed-0 \
        /tmp/ft-rolling-0 --skip 40 --plants 200

A fine-tuning or a distillation selects its agent on the task's first 40 validation plants; this runs the two
controllers (agent folders or names) on the next `--plants` validation plants and prints the second's paired
difference from the first (mean and CVaR-20, 95 % bootstrap intervals) as one JSON line. Held-out plants are
never touched: those are the benchmark's.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from millvib_env.catalog.factory import load_controller
from millvib_env.evaluation.evaluate import run_episodes
from millvib_env.evaluation.stats import paired_difference
from millvib_env.tasks import get_task


def pair(first, second, task, skip: int = 40, plants: int = 200) -> dict:
    """The paired difference of `second` from `first` (controllers) on `task`'s validation plants skip..skip+plants."""
    start = task.seeds["validation"].start + skip
    if skip + plants > len(task.seeds["validation"]):
        raise ValueError(f"--skip {skip} --plants {plants} is invalid: the task has {len(task.seeds['validation'])} "
                         "validation plants")
    seeds = list(range(start, start + plants))
    costs = [np.array([r["cost"] for r in run_episodes(c, seeds, task=task)]) for c in (first, second)]
    d = paired_difference([costs[1]], costs[0])
    return {"plants": f"{seeds[0]}-{seeds[-1]}", "first": float(costs[0].mean()), "second": float(costs[1].mean()),
            "diff_rel": d["cost_diff_rel"], "ci": d["ci"], "cvar20_diff_rel": d["cvar20_diff_rel"],
            "cvar20_ci": d["cvar20_ci"]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("first")
    p.add_argument("second")
    p.add_argument("--task", default=None, help="the task (default: the first agent's)")
    p.add_argument("--skip", type=int, default=40, help="validation plants the selection used (default 40)")
    p.add_argument("--plants", type=int, default=200, help="validation plants to run (default 200)")
    a = p.parse_args(argv)
    first = load_controller(a.first, a.task)
    task = get_task(a.task) if a.task else first.task
    second = load_controller(a.second, task)
    print(json.dumps({"controllers": [a.first, a.second], **pair(first, second, task, a.skip, a.plants)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
