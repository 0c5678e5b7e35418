"""Evaluation curves of the shipped agents' training runs, one panel per agent, one line per seed:
the evidence behind a card's note that fewer steps were enough.

    python scripts/plot_training_curves.py [--runs runs] [--out docs/agents/training_curves.png]

Reads each seed's shipped curve (agents/<name>/seed-<s>/evaluations.npz, which `millvib train
--save-dir` writes), else its run folder LOG_DIR/<algo>_<env>[_<task>]_s<seed>/eval/evaluations.npz
(runs are not shipped: seeds trained before the curve was shipped are drawn only where their run
folder is on this machine). The mean evaluation reward over 8 plants is noisy: a running median
over 10 evaluations is drawn.
"""
import argparse
import json
from pathlib import Path

import numpy as np

from millvib_env._paths import agents_dir, save_figure
from millvib_env.catalog.agents import agent_seed_folders, list_agents
from millvib_env.catalog.manifest import EVAL_CURVE


def run_folder(runs: Path, card: dict) -> Path:
    task = card.get("task", "startup")
    stem = f"{card['algo']}_{card['env_id']}" + ("" if task == "startup" else f"_{task}") + f"_s{card['seed']}"
    for parent in [runs] + sorted(p for p in runs.iterdir() if p.is_dir()):
        if (parent / stem / "eval" / EVAL_CURVE).exists():
            if json.loads((parent / stem / "card.json").read_text()).get("env_kwargs") == card.get("env_kwargs"):
                return parent / stem
    raise FileNotFoundError(stem)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="runs")
    ap.add_argument("--out", default="docs/agents/training_curves.png")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list_agents()
    cols = 3
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.2 * rows), squeeze=False, layout="constrained")
    for ax, name in zip(axes.flat, names):
        for seed, folder in agent_seed_folders(agents_dir() / name).items():
            card = json.loads((folder / "card.json").read_text())
            try:
                shipped = folder / EVAL_CURVE
                ev = np.load(shipped if shipped.is_file() else run_folder(Path(args.runs), card) / "eval" / EVAL_CURVE)
            except (FileNotFoundError, OSError):
                continue
            r = ev["results"].mean(axis=1)
            med = np.array([np.median(r[max(0, i - 9):i + 1]) for i in range(len(r))])
            ax.plot(ev["timesteps"] / 1e6, med, lw=1, label=f"seed {seed}")
        ax.set(title=name, xlabel="steps (M)", ylabel="eval reward (median of 10)")
        ax.title.set_fontsize(9)
        ax.grid(alpha=0.3)
        if ax.lines:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no training runs here", ha="center", transform=ax.transAxes)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    print(f"wrote {save_figure(fig, args.out, dpi=90)}")


if __name__ == "__main__":
    main()
