"""Where the preview bound's room is: `mpc-preview` with parts of its knowledge of the future withdrawn, on the
saved benchmark's held-out plants (rerun `millvib benchmark --task T --all-seeds --out docs/benchmark/v1/T` first).

    MILLVIB_NUM_THREADS=1 python scripts/bound_knowledge.py --task rolling --jobs 2 \
        > docs/benchmark/v1/rolling/bound-knowledge.md

`mpc-preview` knows the plant's parameters and state and, over its 20 ms preview, the exact course of the set-point,
the force steps, the rolls' eccentricity and the pump's ripple (`control.mpc`). Each row below withdraws part of
that (`MPCSettings.ahead`: a course not known ahead is held at its value now, as `mpc-oracle` holds them all) or
gives it the force steps as the measured preview predicts them (`MPCSettings.force_steps: gauge`: the entry gauge's
timing, force-model and noise errors, the students' own preview). The last such row knows the future only as the
students do, and the plant and its state exactly: the room it shows above `pid-pf-preview` is what the preview set's
information leaves to a controller that could identify the plant and its state perfectly. It is a certainty-
equivalent controller (it takes the gauge's forecast as exact), not a bound: the table says where a student beats
it. The per-plant costs are written beside the benchmark (bound-knowledge.json) with the bound's own; a rerun
reuses them where the saved bound's costs are the benchmark's.
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
FF = "pid-pf-preview"
BOUND = "mpc-preview"
#: the students' preview (their observation's look-aheads, loop samples), which the gauge rows' environments measure
PREVIEW = [1, 2, 4, 8, 16, 24, 32, 40]
#: the variants: label -> (the courses known ahead, where the force steps come from)
VARIANTS = {
    "without the pump's ripple ahead": (("setpoint", "force_steps", "eccentricity"), "plant"),
    "without the eccentricity ahead": (("setpoint", "force_steps", "ripple"), "plant"),
    "without the force steps ahead": (("setpoint", "eccentricity", "ripple"), "plant"),
    "the force steps as the gauge measures them": (("setpoint", "force_steps", "eccentricity", "ripple"), "gauge"),
    "the students' preview (gauge steps, no eccentricity or ripple ahead)": (("setpoint", "force_steps"), "gauge"),
}
ORACLE = "mpc-oracle"
ENV_KWARGS = {"observation": {"preview_samples": PREVIEW, "preview_gauge": "measured"}}


def _costs(task: str, seeds: list[int], ahead: tuple, force_steps: str) -> list[float]:
    """The bound with settings (`ahead`, `force_steps`) on `seeds`, in an environment that measures the preview."""
    from dataclasses import replace

    from millvib_env.catalog.factory import load_controller
    from millvib_env.control.mpc import MPCPolicy
    from millvib_env.evaluation.evaluate import run_episodes
    from millvib_env.tasks import get_task

    t = get_task(task)
    base = load_controller(BOUND, task=t)
    assert isinstance(base, MPCPolicy)
    ctrl = MPCPolicy(BOUND, replace(base.settings, ahead=ahead, force_steps=force_steps))
    return [float(r["cost"]) for r in run_episodes(ctrl, seeds, task=t, env_kwargs=ENV_KWARGS)]


def _run(task: str, seeds: list[int], variant: tuple, jobs: int) -> dict[int, float]:
    parts = [seeds[k::jobs] for k in range(jobs)]
    with ProcessPoolExecutor(jobs) as pool:
        outs = list(pool.map(_costs, [task] * jobs, parts, [variant[0]] * jobs, [variant[1]] * jobs))
    return {s: c for p, o in zip(parts, outs) for s, c in zip(p, o)}


def _pct(d: dict, key: str = "cost_diff_rel", ci: str = "ci") -> str:
    lo, hi = d[ci]
    return f"{d[key]:+.1%} [{lo:+.1%}, {hi:+.1%}]"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="rolling", choices=("startup", "rolling", "change", "varied"))
    ap.add_argument("--jobs", type=int, default=2, help="processes (the plants split between them)")
    ap.add_argument("--plants", type=int, default=None, help="the first N of the benchmark's plants (default: all)")
    args = ap.parse_args(argv)
    if args.jobs < 1 or (args.plants is not None and args.plants < 1):
        ap.error(f"--jobs = {args.jobs} and --plants = {args.plants} are invalid: at least 1 each")

    from millvib_env._paths import write_text_atomic
    from millvib_env.evaluation.benchmark import episode_costs
    from millvib_env.evaluation.stats import cvar, paired_difference

    folder = ROOT / "docs" / "benchmark" / "v1" / args.task
    result = json.loads((folder / "benchmark.json").read_text())
    cost = episode_costs(folder)
    seeds = sorted(p for _, p in cost[FF])[: args.plants]
    ff = np.array([cost[FF][("", s)] for s in seeds])
    bound = np.array([cost[BOUND][("", s)] for s in seeds])
    # the environment that measures the preview runs the same plants and disturbances: the bound's own costs agree
    check = _costs(args.task, seeds[:2], VARIANTS["the force steps as the gauge measures them"][0], "plant")
    if max(abs(c / b - 1.0) for c, b in zip(check, bound[:2])) > 1e-9:
        raise SystemExit(f"{BOUND} costs {check} where the saved benchmark has {bound[:2].tolist()}: rerun it")
    saved_path = folder / "bound-knowledge.json"
    saved = json.loads(saved_path.read_text()) if saved_path.exists() else {}
    # the saved costs are reused only where they were made beside this benchmark's bound (the same per-plant
    # costs): a change to the bound or its plants makes every variant again
    bound_now = {str(s): float(c) for s, c in zip(seeds, bound)}
    if any(saved.get("bound", {}).get(k) != c for k, c in bound_now.items()):
        if saved:
            print("the saved bound's costs are not this benchmark's: every variant is run again", file=sys.stderr)
        saved = {}
    kept: dict = {label: saved.get(label, {}) for label in VARIANTS}
    for label, variant in VARIANTS.items():
        todo = [s for s in seeds if str(s) not in kept[label]]
        if todo:
            print(f"{label}: {len(todo)} plants", file=sys.stderr, flush=True)
            kept[label].update({str(s): c for s, c in _run(args.task, todo, variant, args.jobs).items()})
    bound_saved = {**saved.get("bound", {}), **bound_now}
    write_text_atomic(saved_path, json.dumps({"task": args.task, "bound": bound_saved, **kept}, indent=1) + "\n")
    learned = [n for n, c in result["controllers"].items() if c.get("same_information", {}).get("classical") == FF
               and not n.startswith("dagger-residual")]
    students = {n: [np.array([cost[n][(a, s)] for s in seeds]) for a in sorted({a for a, _ in cost[n]})]
                for n in learned}

    plants = "" if args.plants is None else f" --plants {args.plants}"
    print(f"# {args.task}: what each part of the preview bound's knowledge is worth\n")
    print(f"`MILLVIB_NUM_THREADS=1 python scripts/bound_knowledge.py --task {args.task}{plants} --jobs {args.jobs}`, "
          f"on the saved benchmark's {len(seeds)} held-out plants, paired 95 % intervals. Each row is `{BOUND}` "
          "(the plant's parameters and state known exactly) with part of its knowledge of the next 20 ms withdrawn "
          "(held at its value now) or the force steps ahead as the measured preview predicts them. \"Room above "
          f"{FF}\": (its mean - the row's) / its mean; \"the students' share\": the best student's mean gain over "
          "that room; \"students vs the row\": that student's paired difference (a row a student beats is no "
          "bound).\n")
    print(f"| what `{BOUND}` knows ahead | cost mean | CVaR-20 | vs {FF} | room above {FF} | the students' share | "
          "students vs the row |")
    print("|---|---|---|---|---|---|---|")
    best = min(students, key=lambda n: float(np.mean(students[n]))) if students else None

    def row(label: str, c: np.ndarray) -> None:
        room = (ff.mean() - c.mean()) / ff.mean()
        share = vs = "-"
        if best is not None:
            gain = (ff.mean() - float(np.mean(students[best]))) / ff.mean()
            share = f"{gain / room:.0%}" if room > 0 else "no room"
            vs = f"{best}: {_pct(paired_difference(students[best], c))}"
        print(f"| {label} | {c.mean():.4f} | {float(cvar(c)):.3f} | {_pct(paired_difference([c], ff))} | "
              f"{room:+.1%} | {share} | {vs} |")

    row("everything (the bound, saved)", bound)
    for label in VARIANTS:
        row(label, np.array([kept[label][str(s)] for s in seeds]))
    row(f"nothing ahead (`{ORACLE}`, saved: its own tuned horizon)", np.array([cost[ORACLE][("", s)] for s in seeds]))
    if best is not None:
        m = float(np.mean(students[best]))
        print(f"\nThe students: `{best}` (every training seed), mean {m:.4f}, {(ff.mean() - m) / ff.mean():.1%} "
              f"below `{FF}`'s {ff.mean():.4f}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
