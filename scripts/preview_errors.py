"""Each preview reader's cost under the errors a gauge's preview has, one at a time and larger than the measured
preview's, beside the reference (`pid-pf-robust`, which reads no preview) and the classical preview controller.

    python scripts/preview_errors.py --task varied --controllers pid-pf-preview dagger-on-pid-pf-preview-varied

Variants (`envs.gauge.GaugeSettings`): exact; measured (the benchmark's default: 1 ms RMS timing, 10 % force
model, 10 kN noise); each error alone at three times the measured size; all three at three times; the gauge
failed (`failed: true`: every change ahead missed, no one switching the feedforward off). The plants are
N held-out plants (`Task.heldout_plants(N, 0)`); every controller meets the same ones.
Writes docs/benchmark/v1/preview-errors/<task>.json (atomically) and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from millvib_env._paths import write_text_atomic
from millvib_env.catalog.factory import load_controller
from millvib_env.catalog.information import from_env_kwargs
from millvib_env.evaluation.evaluate import run_episodes
from millvib_env.tasks import get_task

MEASURED = {"transport_s": 0.1, "speed_error": 0.01, "force_model_error": 0.1, "noise_n": 1.0e4}
VARIANTS = {
    "exact": "exact",
    "measured": "measured",
    "timing x3 (3 ms RMS)": {**MEASURED, "speed_error": 0.03, "force_model_error": 0.0, "noise_n": 0.0},
    "force model x3 (30 %)": {**MEASURED, "speed_error": 0.0, "force_model_error": 0.3, "noise_n": 0.0},
    "noise x3 (30 kN)": {**MEASURED, "speed_error": 0.0, "force_model_error": 0.0, "noise_n": 3.0e4},
    "all x3": {**MEASURED, "speed_error": 0.03, "force_model_error": 0.3, "noise_n": 3.0e4},
    "gauge failed": {**MEASURED, "failed": True},
}
REFERENCE = "pid-pf-robust"
#: the classical controller of the readers' information: every other reader is paired with it where it was run
CLASSICAL = "pid-pf-preview"


def _against_classical(episodes: dict, names: list[str], rows: dict) -> dict[str, list[str]]:
    """Each other reader against `CLASSICAL` (where it was run), per variant: the paired relative difference of the
    mean and of the CVaR-20 with their 95 % intervals (`evaluation.stats.paired_difference`), stored in `rows`
    (``vs_classical``) and returned as table cells."""
    from millvib_env.evaluation.stats import paired_difference

    if CLASSICAL not in names:
        return {}
    cells: dict[str, list[str]] = {}
    for name in (n for n in names if n != CLASSICAL):
        cells[name] = []
        for label in VARIANTS:
            d = paired_difference([episodes[(name, label)]], episodes[(CLASSICAL, label)])
            rows[name][label]["vs_classical"] = {k: d[k] for k in ("cost_diff_rel", "ci", "cvar20_diff_rel",
                                                                   "cvar20_ci")}
            cells[name].append(f"{d['cost_diff_rel']:+.1%} [{d['ci'][0]:+.1%}, {d['ci'][1]:+.1%}]; "
                               f"{d['cvar20_diff_rel']:+.1%} [{d['cvar20_ci'][0]:+.1%}, {d['cvar20_ci'][1]:+.1%}]")
    return cells


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True)
    p.add_argument("--controllers", nargs="+", required=True, help="preview readers (the reference is added)")
    p.add_argument("--plants", type=int, default=100)
    p.add_argument("--out", default=None, help="default docs/benchmark/v1/preview-errors/<task>.json")
    args = p.parse_args(argv)
    t = get_task(args.task)
    seeds = t.heldout_plants(args.plants, 0)
    ref = np.array([r["cost"] for r in run_episodes(load_controller(REFERENCE, t), seeds, task=t)])
    rows: dict = {REFERENCE: {"reads_preview": False, "cost_mean": float(ref.mean())}}
    episodes: dict = {}  # each reader's costs per variant, for the pairs against the classical preview controller
    for name in args.controllers:
        ctrl = load_controller(name, t)
        if "gauge" not in from_env_kwargs(ctrl.env_kwargs):
            sys.exit(f"--controllers: {name} reads no preview")
        row: dict = {"reads_preview": True}
        for label, gauge in VARIANTS.items():
            cost = np.array([r["cost"] for r in run_episodes(
                ctrl, seeds, task=t, env_kwargs={"observation": {"preview_gauge": gauge}})])
            episodes[(name, label)] = cost
            worse = cost / ref - 1.0
            row[label] = {"cost_mean": float(cost.mean()), "vs_reference": float(cost.mean() / ref.mean() - 1.0),
                          "plants_worse_than_reference_by_20pct": int(np.sum(worse > 0.2))}
            print(f"{name:40s} {label:24s} {cost.mean():.4f} ({row[label]['vs_reference']:+.1%} vs reference)",
                  file=sys.stderr)
        rows[name] = row
    pairs = _against_classical(episodes, args.controllers, rows)
    out = Path(args.out or f"docs/benchmark/v1/preview-errors/{t.name}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps({"task": t.name, "plants": [int(s) for s in seeds], "variants": VARIANTS,
                                       "controllers": rows, "command": "python scripts/preview_errors.py "
                                       + " ".join(argv if argv is not None else sys.argv[1:])}, indent=2))
    print(f"| controller | {REFERENCE} | " + " | ".join(VARIANTS) + " |")
    print("|---|---|" + "---|" * len(VARIANTS))
    for name in args.controllers:
        cells = [f"{rows[name][v]['cost_mean']:.3f} ({rows[name][v]['vs_reference']:+.1%})" for v in VARIANTS]
        print(f"| {name} | {ref.mean():.3f} | " + " | ".join(cells) + " |")
    if pairs:
        print(f"\nAgainst {CLASSICAL}, paired on the same plants (mean [95 % interval]; CVaR-20 [interval]):\n")
        print("| controller | " + " | ".join(VARIANTS) + " |")
        print("|---|" + "---|" * len(VARIANTS))
        for name, cells in pairs.items():
            print(f"| {name} | " + " | ".join(cells) + " |")
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
