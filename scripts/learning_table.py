"""The README's headline table: per task, the room above the classical controller of each information set and
what the best learned controller of that set takes of it, from each task's saved benchmark.

    python scripts/learning_table.py      # after `millvib benchmark --task T --all-seeds --out docs/benchmark/v1/T`
    python scripts/learning_table.py docs/benchmark/v1/second-draw    # a folder of <task>.json (--json) results

Columns: the preview set's classical controller (`pid-pf-preview`) against the reference; the room above it
(`(classical - bound) / classical`, mean and CVaR-20, paired 95 % intervals); the best learned row of that set
(the lowest mean validation cost of its seeds' cards, as the benchmark's group 'answer' chooses: never chosen on
these plants) against it, on the mean, the CVaR-20 and severity, and the share of the room it takes
(its mean gain over the room's mean); the agents trained by reinforcement learning against the classical
controller of their own set: the `loop` set's gain schedulers and the preview set's PPO fine-tunings
(`millvib finetune`), each on the mean.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from millvib_env.catalog.agents import agent_validation_cost

ROOT = Path(__file__).resolve().parent.parent
TASKS = ("startup", "rolling", "change", "varied")
PREVIEW = "loop+force+schedule+gauge"


def pct(x: float, ci=None) -> str:
    s = f"{100 * x:+.1f} %"
    return s + (f" [{100 * ci[0]:+.1f}, {100 * ci[1]:+.1f}]" if ci else "")


def learned(result: dict, info: str) -> list[str]:
    return [n for n, c in result["controllers"].items() if c.get("information") == info and "per_seed" in c]


def main(argv: list[str]) -> int:
    folder = Path(argv[0]) if argv else None
    print("| task | `pid-pf-preview` vs `pid-pf-robust`, mean | room above it, mean / CVaR-20 | best learned of the "
          "preview set (by validation) | vs `pid-pf-preview`: mean / CVaR-20 / severity | share of the room (mean) | "
          "RL agents vs the classical controller of their set, mean |")
    print("|---|---|---|---|---|---|---|")
    for task in TASKS:
        path = folder / f"{task}.json" if folder else ROOT / "docs" / "benchmark" / "v1" / task / "benchmark.json"
        r = json.loads(path.read_text())
        c = r["controllers"]
        pre = r["information"][PREVIEW]
        vs_ref = c["pid-pf-preview"]["paired"]["pid-pf-robust"]
        ref = pct(vs_ref["cost_diff_rel"], vs_ref["ci"])
        room = f"{pct(pre['room_mean'], pre['room_mean_ci'])} / {pct(pre['room_cvar20'], pre['room_cvar20_ci'])}"
        rows = learned(r, PREVIEW)
        best = min(rows, key=agent_validation_cost) if rows else None  # chosen as the answer group chooses
        if best:
            s = c[best]["same_information"]
            gain = f"{pct(s['cost']['cost_diff_rel'], s['cost']['ci'])} / " \
                   f"{pct(s['cost']['cvar20_diff_rel'], s['cost']['cvar20_ci'])} / " \
                   f"{pct(s['severity']['cost_diff_rel'], s['severity']['ci'])}" + \
                   (", tracking flag" if s["tracking_flag"] else "")
            taken = -s["cost"]["cost_diff_rel"] / pre["room_mean"]
            share = f"{100 * taken:.1f} %" if taken > 0 else "none (dearer)"
        else:
            gain, share = "-", "-"
        loop = []
        for n in learned(r, "loop") + [n for n in rows if n.startswith(("ppo-", "sac-"))]:
            s = c[n]["same_information"]
            loop.append(f"{n} {pct(s['cost']['cost_diff_rel'], s['cost']['ci'])} ({s['classical']})")
        print(f"| {task} | {ref} | {room} | {best or '-'} | {gain} | {share} | {'; '.join(loop) or '-'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
