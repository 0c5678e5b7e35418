"""Each learned row's worst plants against the classical controller of its own information, from the benchmark's
saved episodes (docs/benchmark/v1/<task>/benchmark.json and episodes.csv; rerun those first).

    python scripts/worst_plants.py > docs/benchmark/v1/worst-plants.md

Per learned row (an agent: its rows carry a training seed) and task: the share of its (seed, plant) episodes that
cost more than 1.2 x the classical controller's episode on the same plant, and its five worst plants by that ratio.
"""

from __future__ import annotations

import csv
import json
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TASKS = ("startup", "rolling", "change", "varied")
WORSE = 1.2


def rows(task: str):
    folder = ROOT / "docs" / "benchmark" / "v1" / task
    result = json.loads((folder / "benchmark.json").read_text())
    cost: dict = defaultdict(dict)
    learned = set()
    with open(folder / "episodes.csv") as fh:
        for r in csv.DictReader(fh):
            cost[r["controller"]][(r["agent_seed"], int(r["seed"]))] = float(r["cost"])
            if r["agent_seed"]:
                learned.add(r["controller"])
    for name in sorted(learned):
        classical = result["controllers"][name]["same_information"]["classical"]
        base = {plant: c for (_, plant), c in cost[classical].items()}
        ratios = sorted(((c / base[plant], seed, plant) for (seed, plant), c in cost[name].items()), reverse=True)
        share = sum(r > WORSE for r, _, _ in ratios) / len(ratios)
        worst = ", ".join(f"{plant} (seed {seed}): {r:.2f}" for r, seed, plant in ratios[:5])
        yield task, name, classical, len(ratios), share, worst


def main() -> int:
    print("# Learned rows: their worst plants against the classical controller of their information\n")
    print("`python scripts/worst_plants.py`, from each task's `millvib benchmark --task T --all-seeds --out "
          "docs/benchmark/v1/T` (200 held-out plants, every training seed, measured preview). A ratio is the "
          "learned row's cost over the classical controller's on the same plant.\n")
    print(f"| task | learned row | its classical controller | episodes | share costing > {WORSE:g} x | "
          "five worst plants (ratio) |")
    print("|---|---|---|---|---|---|")
    for task in TASKS:
        for t, name, classical, n, share, worst in rows(task):
            print(f"| {t} | {name} | {classical} | {n} | {share:.1%} | {worst} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
