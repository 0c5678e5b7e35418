"""Copy each task's results from docs/benchmark/<version>/<task>/ into docs/results.md (each task's compact table,
v1 only) and into docs/benchmark.md (the full tables).

    millvib benchmark --task T --all-seeds --out docs/benchmark/v1/T    # for each task, then
    python scripts/readme_results.py [startup rolling change] [--version v1]

Fills the blocks between ``<!-- results: TASK -->`` and ``<!-- end results -->`` in docs/results.md (a compact
table from benchmark.json, the loop as commissioned) and ``<!-- results: VERSION TASK -->`` in
docs/benchmark.md (benchmark.md's main table, its actuator table, its seed-spread table and its note on the
normalised score). The verdicts are prose: reread them against the tables.
"""
import argparse
import json
import re
from pathlib import Path

from millvib_env._paths import write_text_atomic
from millvib_env.tasks import list_tasks

ROOT = Path(__file__).resolve().parents[1]


def _table(lines: list[str], start: int) -> list[str]:
    end = start
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return lines[start:end]


def full_block(md: str) -> list[str]:
    lines = md.splitlines()
    first = next(i for i, x in enumerate(lines) if x.startswith("| controller | seeds |"))
    block = [lines[0], ""] + _table(lines, first)
    actuator = [i for i, x in enumerate(lines) if x.startswith("The actuator (")]
    if actuator:
        block += ["", lines[actuator[0]], ""] + _table(lines, actuator[0] + 2)
    spread = [i for i, x in enumerate(lines) if x.startswith("Spread over training seeds")]
    if spread:
        block += ["", lines[spread[0]], ""] + _table(lines, spread[0] + 2)
    note = [x for x in lines if x.startswith("On this task pid-oracle")][:1]
    block += ["", *note] if note else []
    room = [i for i, x in enumerate(lines) if x.startswith("The room to learn") or x.startswith("Same information")]
    if room:
        end = next(i for i, x in enumerate(lines) if x.startswith("Vibration detail"))
        block += [""] + [x for x in lines[room[0]:end]]
        while block and not block[-1].strip():
            block.pop()
    return block


def _pct(d: dict | None, key: str, ci: str) -> str:
    return f"{100 * d[key]:+.1f} % [{100 * d[ci][0]:+.1f}, {100 * d[ci][1]:+.1f}]" if d else "-"


def headline_block(data: dict) -> list[str]:
    """docs/results.md's table of a task: each controller's information set, its cost, against the reference and
    against the classical controller of its own information (cost and severity, paired), then each set's
    classical controller, bound and room."""
    ref = data["reference"]
    lines = [f"| controller | information | cost mean | cost CVaR-20 | vs {ref}: mean | vs its classical: mean | "
             "CVaR-20 | severity |", "|---|---|---|---|---|---|---|---|"]
    for name, s in data["controllers"].items():
        paired = s.get("paired", {})
        mean = f"{s['cost_mean']:.3g} [{s['cost_mean_ci'][0]:.3g}, {s['cost_mean_ci'][1]:.3g}]"
        cvar = f"{s['cost_cvar20']:.3g} [{s['cost_cvar20_ci'][0]:.3g}, {s['cost_cvar20_ci'][1]:.3g}]"
        shown = f"**{name}**" if name == ref else name
        same = s.get("same_information")
        against = (f"{_pct(same['cost'], 'cost_diff_rel', 'ci')} ({same['classical']})",
                   _pct(same["cost"], "cvar20_diff_rel", "cvar20_ci"),
                   _pct(same["severity"], "cost_diff_rel", "ci") + (" (tracking flag)" if same["tracking_flag"]
                                                                    else "")) if same else ("-", "-", "-")
        lines.append(f"| {shown} | {s.get('information', '-')} | {mean} | {cvar} | "
                     f"{_pct(paired.get(ref), 'cost_diff_rel', 'ci')} | {' | '.join(against)} |")
    info = data.get("information")
    if info:
        lines += ["", "| information | its classical | its bound | room, mean | room, CVaR-20 | bound holds |",
                  "|---|---|---|---|---|---|"]
        for target, e in info.items():
            room = ((_pct(e, "room_mean", "room_mean_ci"), _pct(e, "room_cvar20", "room_cvar20_ci"))
                    if "room_mean" in e else ("-", "-"))
            holds = "-" if "bound_holds" not in e else ("yes" if e["bound_holds"] else
                                                           "**no**: " + ", ".join(e["beaten_by"]))
            lines.append(f"| {target} | {e['classical'] or '-'} | {e['bound'] or '-'} | {room[0]} | {room[1]} | "
                         f"{holds} |")
    return lines


def fill(text: str, task: str, block: list[str], where: str) -> str:
    pattern = re.compile(rf"(<!-- results: {re.escape(task)} -->\n).*?(<!-- end results -->)", re.S)
    if not pattern.search(text):
        raise SystemExit(f"{where} has no block <!-- results: {task} --> ... <!-- end results -->")
    return pattern.sub(lambda m: m.group(1) + "\n".join(block) + "\n" + m.group(2), text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tasks", nargs="*", metavar="TASK",
                    help=f"tasks to copy ({', '.join(list_tasks())}; default all)")
    ap.add_argument("--version", default="v1", choices=["v0", "v1"],
                    help="the results of which environment version (default v1; docs/results.md shows v1 only)")
    args = ap.parse_args()
    for task in args.tasks:
        if task not in list_tasks():
            ap.error(f"task {task!r} is not one of {', '.join(list_tasks())}")
    readme, docs = ROOT / "docs" / "results.md", ROOT / "docs" / "benchmark.md"
    r_text, d_text = readme.read_text(), docs.read_text()
    for task in args.tasks or list_tasks():
        folder = ROOT / "docs" / "benchmark" / args.version / task
        if not (folder / "benchmark.json").is_file() or not (folder / "benchmark.md").is_file():
            ap.error(f"{folder} has no benchmark.json / benchmark.md: run `millvib benchmark --task {task} "
                     f"--env-version {args.version} --all-seeds --out {folder.relative_to(ROOT)}` first")
        data = json.loads((folder / "benchmark.json").read_text())
        if args.version == "v1":
            r_text = fill(r_text, task, headline_block(data), "docs/results.md")
        d_text = fill(d_text, f"{args.version} {task}", full_block((folder / "benchmark.md").read_text()),
                      "docs/benchmark.md")
        print(f"{'docs/results.md and ' if args.version == 'v1' else ''}docs/benchmark.md: {task} from "
              f"{folder.relative_to(ROOT)}")
    write_text_atomic(readme, r_text)
    write_text_atomic(docs, d_text)


if __name__ == "__main__":
    main()
