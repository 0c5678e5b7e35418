"""Arguments of `millvib train` and `millvib benchmark` (kept apart so `millvib --help` stays fast)."""

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


def add_train_args(p: argparse.ArgumentParser, func) -> None:
    p.add_argument("--algo", required=True, choices=["ppo", "sac", "recurrentppo"],
                   help="algorithm; hyperparameters come from configs/agents/<algo>.yml")
    p.add_argument("--env", default="MillVib-GainSchedule-v1",
                   help="environment id, the key in the YAML (default MillVib-GainSchedule-v1: the loop as "
                        "commissioned; -v0 ids train on the paper's analog loop)")
    p.add_argument("--task", default="startup",
                   help="task whose episodes and training seeds to use: startup, rolling, change or varied "
                        "(default startup)")
    seeds = p.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=int, default=0,
                       help="training seed, 0-49 (default 0); it picks the task's training and evaluation plants")
    seeds.add_argument("--seeds", type=int, nargs="+", metavar="SEED",
                       help="several training seeds, each its own run folder and model card; run in --jobs local "
                            "processes (with --save-dir D, seed s goes to D/seed-<s>/)")
    p.add_argument("--jobs", type=int, default=2,
                   help="local processes for --seeds (default 2: two trainings at a time, one plant thread each)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="run each seed as a Ray task (1 CPU each): on a local cluster, or on the running cluster at "
                        "ADDRESS (e.g. auto, ray://head:10001); needs pip install -e '.[ray]'")
    p.add_argument("--n-timesteps", type=int, help="override the YAML's n_timesteps")
    p.add_argument("--config", help="hyperparameter YAML: a file, or a shipped one by name from any directory (pf/ppo: "
                        "configs/agents/pf/ppo.yml, the shipped agents'; default configs/agents/<algo>.yml)")
    p.add_argument("--log-dir", default="runs",
                   help="TensorBoard logs and checkpoints go to LOG_DIR/<algo>_<env>_s<seed> "
                        "(LOG_DIR/<algo>_<env>_<task>_s<seed> on rolling and change)")
    p.add_argument("--save-dir", help="where the final model, VecNormalize stats and model card go "
                                      "(default: the run folder)")
    p.add_argument("--resume", action="store_true",
                   help="continue from the run folder's newest intact checkpoint (checkpoints are trusted code: "
                        "they are unpickled)")
    p.add_argument("--eval-freq", type=int, default=10_000, help="evaluate every N environment steps (default 10000)")
    p.add_argument("--n-eval-episodes", type=int, default=8, help="episodes per evaluation (default 8)")
    p.add_argument("--checkpoint-freq", type=int, default=20_000, help="checkpoint every N steps (default 20000)")
    p.add_argument("--validation-episodes", type=int, default=40, metavar="N",
                   help="the model card's validation: the first N of the task's validation plants (default 40, as "
                        "the shipped agents'; fewer for a quick trial)")
    p.add_argument("--note", help="a sentence for the model card (e.g. why n_timesteps was lowered)")
    p.add_argument("--select", choices=["last", "best", "trained"], default="last",
                   help="ship the final policy (default), the best one on the fixed evaluation plants, the "
                        "starting policy included (best), or the best one once training started (trained: never "
                        "the untrained policy); --n-eval-episodes plants, the same every evaluation")
    p.add_argument("--init-from", metavar="AGENT", default=None,
                   help="start from this PPO agent (a shipped name or a folder, e.g. a student of millvib distill): "
                        "its environment, network weights and observation statistics; RL then fine-tunes it "
                        "(configs/agents/on-preview/ppo.yml)")
    p.add_argument("--critic-warmup", type=int, default=0, metavar="STEPS",
                   help="with --init-from: the first STEPS train the critic alone, the actor held as it started "
                        "(default 0)")
    p.add_argument("--backend", choices=["auto", "sb3", "sbx"], default="auto",
                   help="learner library: sb3 (Stable-Baselines3, PyTorch) or sbx (its JAX port, PPO and SAC, same "
                        "hyperparameter files; pip install -e '.[sbx]'); auto (default): sbx for SAC where it is "
                        "installed, else sb3. A SAC trained with sbx is saved in SB3's format (it loads without JAX)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=func)


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
                        "students on it "
                        "and mpc-preview, which gives the room) (default: every baseline "
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
    p.add_argument("--preview", default="measured", choices=["measured", "exact"],
                   help="the preview every controller that reads one gets (the students, pid-pf-preview): measured, "
                        "as an entry gauge gives it (timing, force-model and noise errors, no eccentricity: "
                        "docs/environments.md; default), or exact, the plant's own course. mpc-preview always knows "
                        "the exact course")
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
