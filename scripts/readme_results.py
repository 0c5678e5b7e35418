"""Copy each task's result tables from docs/benchmark/<task>/benchmark.md into the README.

    millvib benchmark --task T --all-seeds --out docs/benchmark/T    # for each task, then
    python scripts/readme_results.py [startup rolling change]

Replaces, under the README's `#### <task>:` heading, the block from the main table to the line
before the paired-difference map with the benchmark's main table, its seed-spread table and its
note on the normalised score. The verdict paragraphs are prose: reread them against the new tables.
"""
import argparse
from pathlib import Path

from millvib_env._paths import write_text_atomic
from millvib_env.tasks import list_tasks

ROOT = Path(__file__).resolve().parents[1]


def _table(lines: list[str], start: int) -> list[str]:
    end = start
    while end < len(lines) and lines[end].startswith("|"):
        end += 1
    return lines[start:end]


def results_block(md: str) -> list[str]:
    lines = md.splitlines()
    main = _table(lines, next(i for i, x in enumerate(lines) if x.startswith("| controller | seeds |")))
    block = main + [""]
    spread = [i for i, x in enumerate(lines) if x.startswith("Spread over training seeds")]
    if spread:
        block += [lines[spread[0]], ""] + _table(lines, spread[0] + 2) + [""]
    block += [x for x in lines if x.startswith("On this task pid-oracle")][:1]
    return block + ([""] if block[-1] else [])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tasks", nargs="*", metavar="TASK",
                    help=f"tasks to copy ({', '.join(list_tasks())}; default all)")
    args = ap.parse_args()
    readme = ROOT / "README.md"
    lines = readme.read_text().splitlines()
    for task in args.tasks:
        if task not in list_tasks():
            ap.error(f"task {task!r} is not one of {', '.join(list_tasks())}")
    for task in args.tasks or list_tasks():
        source = ROOT / "docs" / "benchmark" / task / "benchmark.md"
        if not source.is_file():
            ap.error(f"{source} is missing: run `millvib benchmark --task {task} --all-seeds --out {source.parent}` first")
        md = source.read_text()
        head = next(i for i, x in enumerate(lines) if x.startswith(f"#### {task}:"))
        start = next(i for i in range(head, len(lines)) if lines[i].startswith("| controller | seeds |"))
        stop = next(i for i in range(start, len(lines)) if lines[i].startswith("![paired"))
        lines[start:stop] = results_block(md)
        print(f"README: {task} tables from docs/benchmark/{task}/benchmark.md")
    write_text_atomic(readme, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
