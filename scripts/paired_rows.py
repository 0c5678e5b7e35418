"""Two learned rows of a task's saved benchmark paired seed by seed: each training seed of the second against the
same training seed of the first, on the same held-out plants (a fine-tuned agent against the student it started
from).

    python scripts/paired_rows.py rolling dagger-on-pid-pf-preview-rolling ppo-on-pid-pf-preview-rolling

Reads docs/benchmark/v1/<task>/episodes.csv (`millvib benchmark --task T --all-seeds --out docs/benchmark/v1/T`)
and prints, per seed, and with each row's seeds averaged per plant, the second's relative difference of the mean
cost and of the CVaR-20 from the first's, with 95 % bootstrap intervals over the plants
(`evaluation.stats.paired_difference`).
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from millvib_env.evaluation.stats import paired_difference

ROOT = Path(__file__).resolve().parent.parent


def costs(task: str, version: str = "v1") -> dict:
    """{controller: {(agent seed, plant): cost}} from a task's saved episodes."""
    out: dict = defaultdict(dict)
    with open(ROOT / "docs" / "benchmark" / version / task / "episodes.csv") as fh:
        for r in csv.DictReader(fh):
            out[r["controller"]][(r["agent_seed"], int(r["seed"]))] = float(r["cost"])
    return out


def fmt(d: dict) -> str:
    return (f"{100 * d['cost_diff_rel']:+.2f} % [{100 * d['ci'][0]:+.2f}, {100 * d['ci'][1]:+.2f}]; CVaR-20 "
            f"{100 * d['cvar20_diff_rel']:+.2f} % [{100 * d['cvar20_ci'][0]:+.2f}, {100 * d['cvar20_ci'][1]:+.2f}]")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("task")
    p.add_argument("first")
    p.add_argument("second")
    a = p.parse_args(argv)
    c = costs(a.task)
    for name in (a.first, a.second):
        if name not in c:
            p.error(f"controller {name!r} is not in the {a.task} benchmark's episodes")
    keys = sorted(set(c[a.first]) & set(c[a.second]))
    seeds = sorted({s for s, _ in keys})
    print(f"| {a.second} vs {a.first} ({a.task}) | mean [95 %]; CVaR-20 [95 %] |")
    print("|---|---|")
    for s in seeds:
        k = [key for key in keys if key[0] == s]
        d = paired_difference([np.array([c[a.second][key] for key in k])], np.array([c[a.first][key] for key in k]))
        print(f"| seed {s} ({len(k)} plants) | {fmt(d)} |")
    plants = sorted({p for _, p in keys})

    def per_plant(name):
        return np.array([np.mean([c[name][(s, p)] for s in seeds]) for p in plants])
    d = paired_difference([per_plant(a.second)], per_plant(a.first))
    print(f"| the seeds averaged per plant ({len(plants)} plants) | {fmt(d)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
