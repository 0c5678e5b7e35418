"""`millvib benchmark` and `millvib headroom` from their parsed flags (`flags`): run, print, and write the result's
files as a whole (`--json`, `--out`)."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from millvib_env._paths import atomic_folder, check_output, check_result_folder, write_text_atomic
from millvib_env.tasks import Task
from millvib_env.evaluation.evaluate import CSV_FIELDS
from millvib_env.evaluation.benchmark.lineup import DEPLOYABLE_CLASSICAL, ROOM_BOUNDS
from millvib_env.evaluation.benchmark.plots import (TRACE_SCENARIO, _plot_bars, _plot_paired_plane, _plot_plane,
                                                    _plot_traces)
from millvib_env.evaluation.benchmark.protocol import DEFAULT_PREVIEW_GAUGE
from millvib_env.evaluation.benchmark.report import format_table, public_json
from millvib_env.evaluation.benchmark.run import run_benchmark


def episode_costs(folder: str | Path) -> dict[str, dict[tuple[str, int], float]]:
    """A saved benchmark's per-episode costs (its folder's episodes.csv, written by ``--out``): per controller, per
    (training seed as written, "" for a baseline; plant seed), the cost. For scripts that build on a saved run."""
    costs: dict[str, dict[tuple[str, int], float]] = {}
    with open(Path(folder) / "episodes.csv", newline="") as fh:
        for r in csv.DictReader(fh):
            costs.setdefault(r["controller"], {})[(r["agent_seed"], int(r["seed"]))] = float(r["cost"])
    return costs


def _write_outputs(result: dict, out: Path, task: Task, figures: bool = True) -> list[Path]:
    """Write the result folder of a benchmark of `task` as a whole: into a temporary sibling, then put in place
    (`atomic_folder`), so an interrupted or concurrent run never leaves a mix of two runs' files. Without
    `figures`, the data files only."""

    with atomic_folder(out, command="benchmark") as tmp:
        files = _write_files(result, tmp, task, figures)
    return [out / f.name for f in files]


def _write_files(result: dict, out: Path, task: Task, figures: bool = True) -> list[Path]:
    files = []
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=["controller", *CSV_FIELDS], extrasaction="ignore")
    writer.writeheader()
    for name, recs in result["records"].items():
        for r in recs:
            writer.writerow({"controller": name, **r})
    files.append(write_text_atomic(out / "episodes.csv", buf.getvalue()))
    files.append(write_text_atomic(out / "benchmark.md", format_table(result) + "\n"))
    files.append(write_text_atomic(out / "benchmark.json", json.dumps(public_json(result), indent=2)))
    if not figures:
        return files
    files.append(_plot_plane(result, out / "severity_plane.png"))
    if result.get("reference", "pid-robust") in result["records"] and len(result["records"]) > 1:
        files.append(_plot_paired_plane(result, out / "paired_plane.png"))
    files.append(_plot_bars(result, out / "cost_bars.png"))
    if task.name == "startup":
        files.append(_plot_traces(list(result["controllers"]), out / f"traces_{TRACE_SCENARIO}.png",
                                  result["plants"][0], task=task, version=result.get("env_version", "v0"),
                                  preview=result.get("preview", "exact"), specs=result.get("specs")))
    else:
        files.append(_plot_traces(list(result["controllers"]), out / "traces.png", result["plants"][0],
                                  scenario=None, task=task, version=result.get("env_version", "v0"),
                                  preview=result.get("preview", "exact"), specs=result.get("specs")))
    return files


#: `millvib headroom`'s controllers: the deployable classical ones and every bound
HEADROOM_CONTROLLERS = DEPLOYABLE_CLASSICAL + tuple(ROOM_BOUNDS)


def headroom_from_cli(args) -> int:
    """`millvib headroom`: the benchmark of the deployable classical controllers and the bounds on v1, with the
    room to learn (`room`) printed first."""
    if args.env_version != "v1":
        raise ValueError(f"--env-version {args.env_version} is invalid for headroom: the bounds run on the loop as "
                         "commissioned, v1")
    if args.controllers is None:
        args.controllers = list(HEADROOM_CONTROLLERS)
    return benchmark_from_cli(args)


def benchmark_from_cli(args) -> int:

    check_output(args.json, "--json")
    check_result_folder(args.out, "--out", "benchmark", others=(("--json", args.json),))
    if args.episodes is not None and args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes} is invalid: at least 1")
    if args.seed < 0:
        raise ValueError(f"--seed {args.seed} is invalid: a whole number >= 0 (it seeds the draw of held-out plants)")
    result = run_benchmark(args.controllers, task=args.task, episodes=args.episodes, seed=args.seed,
                           env_version=args.env_version,
                           scenarios=False if args.no_scenarios else None, progress=not args.quiet, ray=args.ray,
                           all_seeds=args.all_seeds, reference=args.reference, jobs=args.jobs,
                           preview=getattr(args, "preview", DEFAULT_PREVIEW_GAUGE))
    print(format_table(result))
    print(f"\n({result['wall_time_s']} s)")
    if args.json:
        write_text_atomic(args.json, json.dumps(public_json(result), indent=2))
        print(f"wrote {args.json}")
    if args.out:
        files = _write_outputs(result, Path(args.out), args.task, figures=not args.no_figures)  # the CLI's Task
        print(f"wrote {len(files)} files to {args.out}")
    return 0
