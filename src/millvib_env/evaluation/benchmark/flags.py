"""The flags of `millvib benchmark` and `millvib headroom` (`command` runs them). Imported when the CLI builds its
parser: it imports nothing of the benchmark, so that `millvib --help` stays fast."""

from __future__ import annotations

import argparse


def jobs_value(text: str) -> int | str:
    """--jobs of `millvib benchmark`: a whole number >= 1 or auto."""
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 1024:
        raise argparse.ArgumentTypeError(f"{text!r} is invalid: a whole number from 1 to 1024, or auto")
    return value


def add_benchmark_args(p: argparse.ArgumentParser, func) -> None:
    p.add_argument("--task", default="startup",
                   help="task: startup (a gap change under load; v0: the paper's 1 mm start), rolling (steady "
                        "rolling), change (the plant changes mid-episode) or varied (rolling on a mill whose "
                        "beta_e, k1, mt and FL vary too); "
                        "configs/tasks.yaml (default startup)")
    p.add_argument("--controllers", nargs="+",
                   help="controllers to evaluate: baselines (pid-paper pid-nominal pid-robust pid-oracle pid-adaptive "
                        "lqr-oracle pid-pf-robust pid-pf-ff pid-pf-oracle; v1: pid-pf-preview mpc-oracle mpc-preview), "
                        "shipped agent "
                        "names (folders under agents/, e.g. ppo-gain-pf; verified against agents/MANIFEST.sha256) or "
                        "paths to agent folders, which are trusted code: SB3 unpickles parts of model.zip; "
                        "exported agents (FILE.onnx from millvib export: onnxruntime, no torch); or the "
                        "groups 'classical' (the deployable classical controllers: pid-paper pid-nominal pid-robust "
                        "pid-adaptive pid-pf-robust pid-pf-ff; v1: pid-pf-preview; seconds) and 'bounds' "
                        "(pid-pf-oracle lqr-oracle; v1: mpc-oracle mpc-preview; minutes) and 'answer' (the mission's "
                        "question in one table: pid-paper, pid-pf-robust; v1: pid-pf-preview, the task's shipped "
                        "learned controller on it with the lowest validation cost and mpc-preview, which gives the "
                        "room) and 'on-preview' (every shipped learned controller on pid-pf-preview) (default: "
                        "every baseline "
                        "and every shipped agent trained on the task)")
    p.add_argument("--env-version", default="v1", choices=["v0", "v1"],
                   help="environment version the baselines run in: v1, the loop as commissioned (a 2 kHz digital "
                        "controller, sensors in the loop, a servo valve with dynamics and a +-10 V amplifier; "
                        "default), or v0, the paper's analog loop with an unlimited valve. Agents run in the "
                        "version they were trained in; the default controllers are those of this version")
    p.add_argument("--episodes", type=int, default=None,
                   help="held-out plants per controller (default 40; 200 with --all-seeds)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the generator that draws the held-out plants from the task's held-out range "
                        "(configs/tasks.yaml), never a training, tuning or validation plant (default 0)")
    p.add_argument("--all-seeds", action="store_true",
                   help="the full protocol: every training seed of every agent, 200 plants by default; without it, "
                        "each agent's lowest seed (a quick run, stated in the output)")
    p.add_argument("--reference", default=None, metavar="NAME",
                   help="the controller every other is paired with on the same plants (the table's 'vs' columns, "
                        "paired_plane.png, the JSON's 'paired'); default pid-pf-robust, the strongest deployable "
                        "classical controller; run even where --controllers leaves it out")
    p.add_argument("--preview", default="measured", choices=["measured", "exact", "failed"],
                   help="the preview every controller that reads one gets (the students, pid-pf-preview): measured, "
                        "as an entry gauge gives it (timing, force-model and noise errors, no eccentricity: "
                        "docs/environments.md; default), exact, the plant's own course, or failed, the gauge's "
                        "signal lost for the episode (every force change ahead missed; the schedule's preview "
                        "stays). mpc-preview always knows the exact course")
    p.add_argument("--no-scenarios", action="store_true", help="skip the named scenarios (startup only)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="spread controllers x episode chunks over Ray tasks: a local cluster, or the running cluster "
                        "at ADDRESS; results equal the local run's for the same seed")
    p.add_argument("--jobs", type=jobs_value, default="auto",
                   help="local worker processes for controllers x episode chunks and the named scenarios, or auto "
                        "(the default): as many as the usable cores (at most 4, and at most MILLVIB_NUM_THREADS "
                        "where set) where an MPC bound or two agent runs (agents x training seeds) take part on at "
                        "least 20 plants, and 1 (this process) otherwise: the classical controllers' workers would "
                        "spend longer loading them than running them, and one agent runs all its plants as one "
                        "job. Each episode depends only on its seeds, so the numbers are the same for any number")
    p.add_argument("--json", metavar="PATH", help="write the summary JSON here")
    p.add_argument("--out", metavar="DIR", help="write per-episode CSV, a markdown table and plots here")
    p.add_argument("--no-figures", action="store_true",
                   help="with --out: write the CSV, the table and the JSON only, not the plots (a few tenths of a "
                        "second each)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=func)
