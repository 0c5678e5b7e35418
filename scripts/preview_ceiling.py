"""How far any schedule of the classical preview controller's gains could go, an adaptive one included:
`pid-pf-preview`'s 17 feedforward gains re-tuned for each held-out plant (`tuning.search.tune_preview_per_plant`),
against the shipped `pid-pf-preview`, its students and `mpc-preview` on the same plants, from the task's saved
benchmark (rerun `millvib benchmark --task T --all-seeds --out docs/benchmark/v1/T` first).

    MILLVIB_NUM_THREADS=1 python scripts/preview_ceiling.py --task varied --episodes 4 --jobs 2 \
        > docs/benchmark/v1/varied/preview-ceiling.md

Two re-tunings per plant:
* for the plant: on `--episodes` other episodes of that plant (its parameters pinned, the disturbances and gauge
  errors of tuning seeds), then scored on its held-out episode: the gains an ideal adaptive controller would
  schedule, one that knew the plant exactly;
* on its own episode: the plant and the very disturbances and gauge errors it is scored on known, what a schedule
  of these gains (fixed over the episode) could reach at most, as far as a local search from the shipped gains finds
  (the cost is not convex once the valve saturates: on a few plants the re-tuning for the plant ends lower).
Both keep `pid-pf-robust`'s PID under the feedforward, as `pid-pf-preview` does. The per-plant gains and costs are
written beside the benchmark (preview-ceiling.json); a rerun reuses what that file holds for the same plants.
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


def _tune(task: str, seeds: list[int], start: list[float], progress: str | None, runs: list | None,
          pins: list | None) -> dict:
    """Each plant's gains on its own episode (`runs` None) or on the episodes `runs` of the plant `pins`, and then
    (for the latter) the cost of those gains on its own episode."""
    from millvib_env.tasks import get_task
    from millvib_env.tuning.search import _pair_costs, tune_preview_per_plant

    t = get_task(task)
    out = tune_preview_per_plant(seeds, task=t, start=start, progress=progress, episodes=runs, params=pins)
    if runs is not None:
        out["cost"] = _pair_costs(np.array(out["gains"]), seeds, t, "measured", 1200).tolist()
    return out


def _run(task: str, seeds: list[int], start: list[float], jobs: int, label: str, runs: list | None = None,
         pins: list | None = None) -> dict:
    """`_tune` over `jobs` processes: per seed (cost, start cost, gains)."""
    parts = [list(range(len(seeds)))[k::jobs] for k in range(jobs)]
    args = [(task, [seeds[i] for i in p], start, label if k == 0 else None,
             None if runs is None else [runs[i] for i in p], None if pins is None else [pins[i] for i in p])
            for k, p in enumerate(parts)]
    with ProcessPoolExecutor(jobs) as pool:
        outs = list(pool.map(_tune, *zip(*args)))
    return {s: (c, c0, g) for o in outs for s, c, c0, g in zip(o["seeds"], o["cost"], o["start_cost"], o["gains"])}


def _plant_episodes(task: str, seeds: list[int], episodes: int) -> tuple[list, list]:
    """For plant j: `episodes` tuning seeds of its own (the task's tuning range, j-th block) and its drawn
    parameters, pinned."""
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.tasks import get_task

    t = get_task(task)
    if episodes * len(seeds) > len(t.seeds["tuning"]):
        raise SystemExit(f"--episodes {episodes} x {len(seeds)} plants is more than the task's "
                         f"{len(t.seeds['tuning'])} tuning seeds")
    batch = EpisodeBatch("MillVib-Valve-v1", len(seeds), config=t.config)
    batch.reset(seeds)
    drawn = [d.name for d in batch.core.settings.cfg.randomize]
    pins = [{k: float(getattr(batch.core.params[i], k)) for k in drawn} for i in range(len(seeds))]
    first = t.seeds["tuning"].start
    return [[first + episodes * j + k for k in range(episodes)] for j in range(len(seeds))], pins


def _pct(d: dict, key: str = "cost_diff_rel", ci: str = "ci") -> str:
    lo, hi = d[ci]
    return f"{d[key]:+.1%} [{lo:+.1%}, {hi:+.1%}]"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="varied", choices=("startup", "rolling", "change", "varied"))
    ap.add_argument("--jobs", type=int, default=2, help="processes (the plants split between them)")
    ap.add_argument("--plants", type=int, default=None, help="the first N of the benchmark's plants (default: all)")
    ap.add_argument("--episodes", type=int, default=2, help="tuning episodes per plant for the plant's re-tuning")
    args = ap.parse_args(argv)
    if args.jobs < 1 or args.episodes < 1:
        ap.error(f"--jobs = {args.jobs} and --episodes = {args.episodes} are invalid: at least 1 each")

    import yaml

    from millvib_env._paths import write_text_atomic
    from millvib_env.evaluation.benchmark import episode_costs
    from millvib_env.evaluation.stats import cvar, paired_difference

    folder = ROOT / "docs" / "benchmark" / "v1" / args.task
    result = json.loads((folder / "benchmark.json").read_text())
    cost = episode_costs(folder)
    seeds = sorted(p for _, p in cost[FF])[: args.plants]
    start = yaml.safe_load((ROOT / "configs" / "control" / "v1" / f"{args.task}.yaml").read_text())[FF]["gains"]
    ff = np.array([cost[FF][("", s)] for s in seeds])
    saved_path = folder / "preview-ceiling.json"
    saved = json.loads(saved_path.read_text()) if saved_path.exists() else {}
    if saved.get("start") != start or saved.get("plant_episodes") != args.episodes:
        saved = {}  # another pid-pf-preview, or another number of tuning episodes: nothing to reuse
    kept: dict = {k: saved.get(k, {}) for k in ("own_episode", "plant")}  # per plant (its seed): cost and gains
    todo = [s for s in seeds if str(s) not in kept["own_episode"]]
    if todo:
        tuned = _run(args.task, todo, start, args.jobs, "on its own episode")
        gap = max(abs(tuned[s][1] / cost[FF][("", s)] - 1.0) for s in todo)
        if gap > 1e-9:
            raise SystemExit(f"the search's start costs {gap:.2e} apart from the benchmark's {FF} episodes: the "
                             "saved benchmark is not of these gains; rerun it")
        kept["own_episode"].update({str(s): {"cost": tuned[s][0], "gains": tuned[s][2]} for s in todo})
    runs, pins = _plant_episodes(args.task, seeds, args.episodes)
    todo = [j for j, s in enumerate(seeds) if str(s) not in kept["plant"]]
    if todo:
        tuned = _run(args.task, [seeds[j] for j in todo], start, args.jobs, "for its plant", [runs[j] for j in todo],
                     [pins[j] for j in todo])
        kept["plant"].update({str(seeds[j]): {"cost": tuned[seeds[j]][0], "gains": tuned[seeds[j]][2],
                                              "tuning_seeds": runs[j]} for j in todo})
    write_text_atomic(saved_path, json.dumps({"task": args.task, "start": start, "plant_episodes": args.episodes,
                                              **kept}, indent=1) + "\n")
    adaptive = np.array([kept["plant"][str(s)]["cost"] for s in seeds])
    ceiling = np.array([kept["own_episode"][str(s)]["cost"] for s in seeds])
    bound = np.array([cost[BOUND][("", s)] for s in seeds])
    learned = [n for n, c in result["controllers"].items() if c.get("same_information", {}).get("classical") == FF]

    print(f"# {args.task}: the classical preview controller re-tuned per plant\n")
    plants = "" if args.plants is None else f" --plants {args.plants}"
    print(f"`MILLVIB_NUM_THREADS=1 python scripts/preview_ceiling.py --task {args.task}{plants} --episodes "
          f"{args.episodes} --jobs {args.jobs}`, on the "
          f"saved benchmark's {len(seeds)} held-out plants (measured preview), paired 95 % intervals. `{FF}` with "
          f"its 17 gains re-tuned **for the plant** (on {args.episodes} other episodes of it: its parameters known, "
          "its disturbances not; the gains an ideal adaptive controller would schedule) and **on its own episode** "
          "(the plant, its disturbances and its gauge errors known: near the most any schedule of the gains could "
          "reach, as far as a local search finds).\n")
    room = ff.mean() - bound.mean()
    print("| controller | cost mean | CVaR-20 | vs pid-pf-preview | vs re-tuned for the plant: mean | CVaR-20 | "
          "vs re-tuned on its episode: mean | share of the room |")
    print("|---|---|---|---|---|---|---|---|")

    def row(name: str, per_seed: list[np.ndarray]) -> None:
        m = float(np.mean(per_seed))
        vs_adaptive = paired_difference(per_seed, adaptive)
        print(f"| {name} | {m:.3f} | {float(cvar(np.concatenate(per_seed))):.3f} | "
              f"{_pct(paired_difference(per_seed, ff))} | {_pct(vs_adaptive)} | "
              f"{_pct(vs_adaptive, 'cvar20_diff_rel', 'cvar20_ci')} | {_pct(paired_difference(per_seed, ceiling))} | "
              f"{(ff.mean() - m) / room:.0%} |")

    row(f"{FF} (shipped)", [ff])
    row(f"{FF} re-tuned for the plant", [adaptive])
    row(f"{FF} re-tuned on its own episode", [ceiling])
    for name in learned:
        agent_seeds = sorted({a for a, _ in cost[name]})
        row(name, [np.array([cost[name][(a, s)] for s in seeds]) for a in agent_seeds])
    row(f"{BOUND} (bound)", [bound])
    return 0


if __name__ == "__main__":
    sys.exit(main())
