"""Arguments of `millvib train` and `millvib distill` (kept apart so `millvib --help` stays fast)."""

from __future__ import annotations

import argparse


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


def add_distill_args(p: argparse.ArgumentParser, func) -> None:
    p.add_argument("--task", default="rolling", help="task: startup, rolling, change or varied (default rolling)")
    p.add_argument("--teacher", default="mpc-preview", choices=["mpc-preview", "mpc-oracle"],
                   help="the oracle that labels every loop sample (default mpc-preview)")
    p.add_argument("--baseline", default=None, choices=["mpc-oracle"],
                   help="label with the teacher's command less this oracle's, from the same state (what the "
                        "preview adds), instead of less the digital PID's own command (default: the PID's)")
    p.add_argument("--seed", type=int, default=0, help="training seed, 0-49: its 100 training plants (default 0)")
    p.add_argument("--resume", action="store_true",
                   help="go on from the last iteration an unfinished run of the same options finished (its journal "
                        "SAVE_DIR.partial, kept after each iteration)")
    p.add_argument("--iterations", type=int, default=4, help="DAgger iterations (default 4)")
    p.add_argument("--episodes", type=int, default=25,
                   help="training episodes per iteration, 1-100 (default 25): the seed's 100 training plants in "
                        "turn, visited again under the next students past the 100th")
    p.add_argument("--epochs", type=int, default=30, help="least-squares epochs per iteration (default 30)")
    p.add_argument("--budget", choices=("pool", "iteration"), default="iteration",
                   help="an epoch's size: 'iteration', one iteration's worth of samples drawn from the pool (a "
                        "constant cost per iteration; Adam's step 1e-3/sqrt(iteration); default), or 'pool', a pass "
                        "over every pooled sample (the fit grows with each iteration; the students distilled before "
                        "this option)")
    p.add_argument("--validation-episodes", type=int, default=40, metavar="N",
                   help="each iteration's student is scored on the first N of the task's validation plants "
                        "(default 40, as the shipped agents')")
    p.add_argument("--validate-from", type=int, default=1, metavar="K",
                   help="score the students of iterations K on only (the earlier ones are not candidates; default "
                        "1: every iteration's)")
    p.add_argument("--batch", type=int, default=1024,
                   help="the least-squares fit's batch of samples (default 1024)")
    p.add_argument("--net", type=int, nargs="+", default=[256, 256], metavar="UNITS",
                   help="the student's hidden layers (default 256 256)")
    p.add_argument("--range-v", type=float, default=100.0,
                   help="the residual's range in volts: action 1 adds this to the PID's command (default 100: "
                        "enough to move the plant ahead of a step against the PID, which pulls back at 1.3 V per "
                        "um; the amplifier still limits the sum to +-10 V)")
    p.add_argument("--history", type=int, nargs="*", default=[1, 2, 4, 8, 16, 32], metavar="K",
                   help="the student also reads the measured channels as they were K loop samples ago, for each K "
                        "(observation.history_samples; default 1 2 4 8 16 32; none: --history with no K)")
    p.add_argument("--filters", type=int, nargs="*", default=[], metavar="TAU",
                   help="the student also reads the measured channels' moving averages and those of their squares, "
                        "per time constant TAU in loop samples (observation.history_filters; default none)")
    p.add_argument("--loop-sample", choices=("current", "previous"), default="current",
                   help="the loop's sample the student reads (observation.loop_sample): 'current', the one its "
                        "action joins at the controller (default), or 'previous', one sample older (the agents "
                        "distilled before this option)")
    p.add_argument("--preview", choices=("measured", "exact"), default="measured",
                   help="the preview the student reads while it learns: measured, as an entry gauge gives it and the "
                        "benchmark runs it (timing, force-model and noise errors, no eccentricity; default), or "
                        "exact (the shipped students')")
    p.add_argument("--on", default=None, choices=["pid-pf-preview"],
                   help="the classical controller the residual sits on: pid-pf-preview, the classical controller of "
                        "the student's own information (its tuned feedforward then runs in the environment, and the "
                        "student learns what it misses within +-RANGE_V; use --range-v 10); default: the "
                        "reference's PID alone")
    p.add_argument("--save-dir", required=True, metavar="DIR",
                   help="the agent folder to write (under agents/ the manifest is updated)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=func)


def add_finetune_args(p: argparse.ArgumentParser, func) -> None:
    p.add_argument("student", metavar="STUDENT",
                   help="the student's agent seed folder (a millvib distill agent, e.g. "
                        "agents/dagger-on-pid-pf-preview-rolling/seed-0); its seed is the run's")
    p.add_argument("--steps", type=int, default=600_000, help="environment steps in all (default 600000)")
    p.add_argument("--warmup", type=int, default=200_000,
                   help="the first steps train the critic alone, the actor held (default 200000)")
    p.add_argument("--eval-every", type=int, default=50_000, metavar="STEPS",
                   help="after the warm-up, score the actor on the validation plants every STEPS (default 50000)")
    p.add_argument("--actor-lr", type=float, default=3e-5, help="the actor's Adam step (default 3e-5)")
    p.add_argument("--critic-lr", type=float, default=3e-4, help="the critic's Adam step (default 3e-4)")
    p.add_argument("--n-envs", type=int, default=16, help="environments stepped together (default 16)")
    p.add_argument("--n-steps", type=int, default=256,
                   help="steps of each environment per PPO update (default 256)")
    p.add_argument("--gamma", type=float, default=0.99,
                   help="PPO's discount per loop sample (default 0.99: a horizon of about 100 samples, 50 ms)")
    p.add_argument("--reward", choices=("episode-cost", "config"), default="episode-cost",
                   help="what PPO maximises: 'episode-cost', each period by what it adds to the episode's cost "
                        "(default), or 'config', the environment's reward (each period's own RMS); the validation "
                        "scores are the cost either way")
    p.add_argument("--validation-episodes", type=int, default=40, metavar="N",
                   help="each score runs the first N of the task's validation plants (default 40, those the "
                        "students were selected on)")
    p.add_argument("--save-dir", required=True, metavar="DIR",
                   help="the agent folder to write (under agents/ the manifest is updated)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=func)
