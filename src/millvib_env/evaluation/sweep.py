"""`millvib sweep`: controllers over many plants, for when 200 episodes are not enough.

The plants are the task's episodes with the swept parameters drawn over wide ranges (`RANGES`; the
others keep the task's own distribution), from held-out seeds of the task. Controllers x chunks of
plants are independent jobs, run in local processes or on Ray (`distributed.run_jobs`); each
episode depends only on its seed, so local and Ray runs give the same numbers. Writes a per-plant
CSV, a summary JSON and maps of the cost over the swept parameters (PNG), as a whole folder.

A long sweep keeps each finished job's episodes at once in a journal beside the folder (`DIR.partial`, JSON
lines: the run, then a line per job, appended as each ends): a run that a Ctrl-C, a crash or a lost cluster
ends says so, and the same command with ``--resume`` runs only the jobs left, to the files an uninterrupted run
writes (an episode's numbers go through JSON unchanged); the journal goes once they are written.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from millvib_env import _interrupt
from millvib_env._checks import integer, shown, shown_path, strings
from millvib_env._figures import log_span, panel_grid
from millvib_env._journal import check_same_run, found, journal_path
from millvib_env._paths import atomic_folder, check_result_folder, save_figure, write_text_atomic
from millvib_env.catalog.factory import load_controller
from millvib_env.distributed import run_jobs
from millvib_env.envs.batch import env_id_for
from millvib_env.params import studied_range
from millvib_env.tasks import Task, takes_task
from millvib_env.evaluation.benchmark import episode_records, format_table, summarize
from millvib_env.evaluation.evaluate import COST_SCALES
from millvib_env.envs.config import DEFAULT_VERSION

__all__ = ["RANGES", "run_sweep", "write_sweep", "sweep_from_cli", "journal_path"]

#: the swept parameters' ranges: c1 and Ct the paper's (log-uniform), the others +-20 % of Table 1
RANGES = {"c1": ("loguniform", *studied_range("c1")), "Ct": ("loguniform", *studied_range("Ct")),
          "beta_e": ("uniform", 5.6e8, 8.4e8), "mt": ("uniform", 960.0, 1440.0), "FL": ("uniform", 1.6e6, 2.4e6)}
#: sweep plants start this far into the task's held-out range (clear of the benchmark's first seeds)
SEED_OFFSET = 40_000
CHUNK = 64


def _randomize(task: Task, params: Sequence[str], version: str = DEFAULT_VERSION) -> dict:
    cfg = task.configs[version]
    out = {d.name: {"dist": d.dist, "low": d.low, "high": d.high} for d in cfg.randomize}
    for name in params:
        if name not in RANGES:
            raise ValueError(f"--params {shown(name)} is invalid: one of {list(RANGES)}")
        dist, lo, hi = RANGES[name]
        out[name] = {"dist": dist, "low": lo, "high": hi}
    return out


@takes_task()
def run_sweep(controllers: Sequence[str], plants: int, *, task: str | Task = "startup",
              params: Sequence[str] = ("c1", "Ct"), seed: int | None = None, ray: str | None = None,
              processes: int = 1, progress: bool = True, env_version: str = "v1", journal: str | Path | None = None,
              resume: bool = False) -> dict:
    """Every controller on `plants` plants; returns {"records": {name: [...]}, "summary": ...}. Baselines run
    in environment version `env_version` (agents in their own). `journal`: a file that keeps each finished job's
    episodes as it ends (module docstring); `resume` goes on from the jobs an unfinished run of the same sweep
    kept there."""

    assert isinstance(task, Task)  # a name was resolved by @takes_task
    t = task
    plants = integer("--plants", plants, lo=1, hi=len(t.seeds["heldout"]) - SEED_OFFSET)
    controllers = strings("controllers", controllers, "controller names")
    params = list(dict.fromkeys(strings("params", params, "parameter names")))
    seed = None if seed is None else integer("seed", seed, lo=0)
    processes = integer("processes", processes, lo=1, hi=1024)

    env_id = env_id_for("gain", env_version)
    randomize = _randomize(t, params, env_version)
    first = t.seeds["heldout"].start + SEED_OFFSET if seed is None else seed
    seeds = list(range(first, first + plants))
    t.check_heldout(seeds)
    for name in controllers:
        load_controller(name, t, version=env_version)  # a bad name fails here, before any job starts
    jobs = [{"name": n, "task": t, "seeds": seeds[i:i + CHUNK], "env_kwargs": {"randomize": randomize},
             "env_id": env_id}
            for n in controllers for i in range(0, plants, CHUNK)]
    run = {"task": t.name, "env_version": env_version, "controllers": controllers, "plants": plants, "params": params,
           "seed": first}
    parts = {} if journal is None else _open_journal(Path(journal), run, resume, len(jobs))
    todo = [i for i in range(len(jobs)) if i not in parts]

    def finished(k: int, part: list) -> None:
        parts[todo[k]] = part
        if journal is not None:
            _record(Path(journal), run, todo[k], part, len(parts), len(jobs))

    run_jobs(episode_records, [jobs[i] for i in todo], ray=ray, processes=processes, progress=progress,
             desc=f"sweep {t.name}", on_result=finished)
    records: dict[str, list] = {n: [] for n in controllers}
    for i, job in enumerate(jobs):
        records[str(job["name"])].extend(parts[i])
    summary = {"task": t.name, "env_version": env_version, "plants": plants, "seed": first, "params": params,
               "ranges": {p: list(RANGES[p]) for p in params},
               "controllers": {n: summarize(r) for n, r in records.items()}}
    return {"records": records, "summary": summary}


def _open_journal(path: Path, run: dict, resume: bool, n_jobs: int) -> dict[int, list]:
    """The jobs an unfinished run of the sweep `run` kept in `path` ({job: its episodes}) with `resume`; else none
    (and no journal may be there: the first finished job starts it). A line cut short by the interruption ends the
    reading: its job runs again."""
    if not found(path, resume, "sweep", "jobs"):
        return {}
    try:
        lines = path.read_text(encoding="utf-8").split("\n")
        head = json.loads(lines[0])
    except (OSError, ValueError) as err:
        raise ValueError(f"sweep journal {shown_path(path)} cannot be read ({type(err).__name__}); delete it to start "
                         "again") from None
    check_same_run(path, head.get("run") if isinstance(head, dict) else None, run, "sweep")
    done: dict[int, list] = {}
    for n, line in enumerate(lines[1:], start=1):
        try:
            item = json.loads(line)
        except ValueError:  # the end, or a line the interruption cut short: the journal goes on after the last job
            if line or n < len(lines) - 1:
                write_text_atomic(path, "\n".join(lines[:n]) + "\n")
            break
        job, recs = (item.get("job"), item.get("records")) if isinstance(item, dict) else (None, None)
        if isinstance(job, bool) or not isinstance(job, int) or not 0 <= job < n_jobs or not isinstance(recs, list) \
                or not all(isinstance(r, dict) for r in recs):
            raise ValueError(f"sweep journal {shown_path(path)} is damaged (a line that is no finished job); delete "
                             "it to start again")
        done[job] = recs
    _interrupt.leave_note(_kept(path, len(done), n_jobs))
    return done


def _record(path: Path, run: dict, job: int, recs: list, n_done: int, n_jobs: int) -> None:
    """Job `job`'s episodes appended to the journal as one line, on the disk before the next job's (the journal
    started, its first line the run, at the first)."""
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps({"run": run}) + "\n")
    with open(path, "a", encoding="utf-8") as f:
        f.write(json.dumps({"job": job, "records": recs}) + "\n")
        f.flush()
        os.fsync(f.fileno())
    _interrupt.leave_note(_kept(path, n_done, n_jobs))


def _kept(path: Path, n_done: int, n_jobs: int) -> str:
    return (f"{n_done} of {n_jobs} jobs are kept in {shown_path(path)}: the same command with --resume goes on from "
            "them") if n_done else ""


def write_sweep(result: dict, out: str | Path, *, figures: bool = True) -> list[Path]:
    """Write a sweep's folder as a whole (`atomic_folder`): plants.csv, summary.json and, with `figures`, maps.png.
    Returns the files written."""

    out = Path(out)
    params = result["summary"]["params"]
    with atomic_folder(out, command="sweep") as tmp:
        buf = io.StringIO()
        fields = ["controller", "seed", *dict.fromkeys(["c1", "Ct", *params]), "cost", "severity_mm_s",
                  "tracking_rms_um", "diverged"]  # record keys (evaluate.EpisodeRecord) and drawn parameters
        writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        for name, recs in result["records"].items():
            for r in recs:
                writer.writerow({"controller": name, **r})
        write_text_atomic(tmp / "plants.csv", buf.getvalue())
        write_text_atomic(tmp / "summary.json", json.dumps(result["summary"], indent=2, default=float))
        if figures:
            save_figure(_maps(result), tmp / "maps.png", dpi=90)
    return [out / "plants.csv", out / "summary.json", *([out / "maps.png"] if figures else [])]


def _maps(result: dict):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.colors import LogNorm
    from matplotlib.ticker import NullFormatter

    params = result["summary"]["params"]
    names = list(result["records"])
    pairs = [(params[i], params[j]) for i in range(len(params)) for j in range(i + 1, len(params))][:3]
    pairs = pairs or [(params[0], "c1" if params[0] != "c1" else "Ct")]
    costs = [r["cost"] for recs in result["records"].values() for r in recs if math.isfinite(r["cost"])]
    norm = LogNorm(vmin=max(min(costs), 1e-3), vmax=max(costs))
    fig, axes, cax = panel_grid(len(names), len(pairs), width=4.5, height=3.8)
    for row, name in enumerate(names):
        recs = result["records"][name]
        for col, (px, py) in enumerate(pairs):
            ax = axes[row, col]
            sc = ax.scatter([r[px] for r in recs], [r[py] for r in recs],
                            c=[min(r["cost"], 1e6) for r in recs], norm=norm, cmap="magma_r", s=12)
            ax.set(xlabel=px, ylabel=py, title=f"{name}: mean cost {np.mean([r['cost'] for r in recs]):.3g}")
            ax.title.set_fontsize(9)
            for axis, p in (("x", px), ("y", py)):
                if RANGES[p][0] == "loguniform":
                    log_span(ax, axis, [r[p] for r in recs])
                    getattr(ax, f"{axis}axis").set_minor_formatter(NullFormatter())
    fig.colorbar(sc, cax=cax, label="episode cost")
    return fig


def sweep_from_cli(args) -> int:

    check_result_folder(args.out, "--out", "sweep")
    journal = journal_path(args.out)
    result = run_sweep(args.controllers, args.plants, task=args.task, params=args.params, seed=args.seed,
                       ray=args.ray, processes=args.jobs, progress=not args.quiet, env_version=args.env_version,
                       journal=journal, resume=args.resume)

    s = result["summary"]
    ranges = ", ".join(f"{p} {lo:g}-{hi:g} ({kind})" for p, (kind, lo, hi) in s["ranges"].items())
    last = s['seed'] + s['plants'] - 1
    title = (f"Sweep on task {s['task']}: {s['plants']} plants, episode seeds {s['seed']}-{last} of "
             f"its held-out range, with {ranges}. Cost = severity / {COST_SCALES['severity_mm_s']} mm/s + tracking "
             f"RMS / {COST_SCALES['tracking_um']} um; [95 % bootstrap intervals]")
    print(format_table({"task": s["task"], "episodes": s["plants"], "seed": s["seed"], "title": title,
                        "cost_scales": dict(COST_SCALES), "controllers": s["controllers"]}))
    files = write_sweep(result, args.out, figures=not args.no_figures)
    journal.unlink(missing_ok=True)
    _interrupt.leave_note("")
    print(f"wrote {len(files)} files to {args.out}")
    return 0
