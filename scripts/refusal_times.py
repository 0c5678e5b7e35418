"""How long each command takes to refuse a damaged file, measured as a user meets it: a fresh `millvib`
process (imports included) over a copy of the configs (`MILLVIB_CONFIGS`) or an agent folder, with one file
replaced by a small damaged one. Prints one row per (file, damage) with the exit status, the seconds and
whether stderr was one line, then the largest time. The guarantee it measures (docs/guarantees.md): no
command takes more than 5 s to refuse a damaged file of under 1 kB.

    python scripts/refusal_times.py [--kinds aliases "a repeated key" ...] [--files tasks.yaml ...]
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: damage -> the file's whole new text (each under 1 kB)
DAMAGE = {
    "aliases": "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{n}: &{n} [{', '.join(['*' + p] * 9)}]\n" for p, n in zip("abcdefgh", "bcdefghi")),
    "a repeated key": "startup: {config: startup}\nstartup: {config: rolling}\n",
    "a 400-digit integer": "kp: " + "9" * 400 + "\n",
    "keys of mixed types": "{1: 2, zz: 3}\n",
    "broken YAML": "a: [1, 2\n",
    "a !!python tag": "!!python/object/apply:os.system ['true']\n",
    "nested 300 deep": "[" * 300 + "]" * 300 + "\n",
    "not UTF-8": b"\xff\xfe\x00\x01",
}
CARD_DAMAGE = {
    "card: not an object": "[1, 2]",
    "card: env_kwargs null": '{"name": "x", "algo": "ppo", "env_id": "MillVib-Valve-v1", "env_kwargs": null}',
    "card: seed 1e400": '{"name": "x", "algo": "ppo", "env_id": "MillVib-Valve-v1", "seed": 1e400}',
    "card: nested 300 deep": "[" * 300 + "]" * 300,
}
BENCH = ["benchmark", "--controllers", "pid-robust", "--episodes", "2", "--no-scenarios", "--quiet"]
#: file under configs/ -> a command that reads it
READERS = {
    "plant/paper.yaml": ["simulate", "--t-end", "0.2"],
    "severity.yaml": ["simulate", "--t-end", "0.2"],
    "tasks.yaml": ["tasks"],
    "env/startup.yaml": BENCH,
    "control/v1/startup.yaml": BENCH,
    "agents/ppo.yml": ["train", "--algo", "ppo", "--n-timesteps", "64", "--quiet"],
}


def _run(argv: list[str], env: dict, cwd: Path) -> tuple[int, float, list[str]]:
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", "import sys; from millvib_cli import main; sys.exit(main())",
                          *argv], capture_output=True, text=True, env=env, cwd=cwd, timeout=600)
    return run.returncode, time.perf_counter() - start, run.stderr.strip().splitlines()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kinds", nargs="+", choices=sorted(DAMAGE), default=sorted(DAMAGE))
    ap.add_argument("--files", nargs="+", choices=sorted(READERS), default=sorted(READERS))
    ap.add_argument("--no-cards", action="store_true", help="skip the damaged agent cards")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in args.files:
            for kind in args.kinds:
                root = tmp / "configs"
                shutil.rmtree(root, ignore_errors=True)
                shutil.copytree(ROOT / "configs", root)
                text = DAMAGE[kind]
                (root / name).write_bytes(text if isinstance(text, bytes) else text.encode())
                env = {**os.environ, "MILLVIB_CONFIGS": str(root)}
                rows.append((name, kind, len(text), *_run(READERS[name], env, tmp)))
        if not args.no_cards:
            for kind, text in CARD_DAMAGE.items():
                agent = tmp / "agent"
                shutil.rmtree(agent, ignore_errors=True)
                shutil.copytree(ROOT / "agents" / "ppo-gain-pf" / "seed-0", agent)
                (agent / "card.json").write_text(text)
                rows.append(("card.json", kind, len(text),
                             *_run(["export", str(agent), "--out", str(tmp / "a.onnx")], dict(os.environ),
                                   tmp)))
    print("| file | damage | bytes | exit | seconds | stderr lines |")
    print("|---|---|---|---|---|---|")
    for name, kind, size, status, seconds, err in rows:
        print(f"| {name} | {kind} | {size} | {status} | {seconds:.2f} | {len(err)} |")
    worst = max(rows, key=lambda r: r[4])
    bad = [r for r in rows if r[3] != 2 or len(r[5]) != 1]
    print(f"\nlargest: {worst[4]:.2f} s ({worst[0]}, {worst[1]}); load {os.getloadavg()[0]:.2f}; "
          f"{len(rows)} refusals, {len(bad)} not one line with exit 2")
    for name, kind, _, status, _, err in bad:
        print(f"  {name} / {kind}: exit {status}: {err[-3:]}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
