"""The `millvib` command: a thin layer over the library. `millvib <command> --help` explains each."""

from __future__ import annotations

import argparse
import math
import signal
import json
import sys
import textwrap
from pathlib import Path

from millvib_env import _interrupt

DESCRIPTION = """\
millvib: vertical vibration of a rolling mill's hydraulic screw-down system.

A verified simulator of the paper's plant (servo valve, cylinder, oil compressibility and
leakage, LuGre seal friction, 115.5 Hz pump pulsation, PID position loop), its vibration
severity (ISO 20816-3-style, mm/s), Gymnasium environments and RL gain schedulers benchmarked against
fixed-gain PIDs.

commands:
  simulate    one closed-loop run: severity, ISO zone, kind of motion, tracking error (--plot)
  reproduce   the paper's three studies (Figs. 4-9 analogues), stability and motion maps
  speed       integrator and environment speed (the tables of docs/performance.md; was 'bench')
  params      the plant parameters: symbol, default (Table 1), unit, meaning, allowed range
  scenarios   the named failure scenarios with the paper PID's measured outcome
  tasks       the benchmark's tasks (startup, rolling, change, varied) and their seed ranges
  tune        tune a task's classical baselines on its tuning plants (--out FILE or --write-config)
  train       train a PPO / SAC / RecurrentPPO agent from configs/agents/
  benchmark   evaluate controllers on a task's held-out plants (and the scenarios)
  headroom    the room to learn on a task: the classical controllers against the MPC bounds (v1)
  distill     teach a residual valve policy with a preview by the MPC oracle (v1)
  finetune    PPO on top of a distilled student, the best on validation plants kept (v1)
  export      a trained agent as an ONNX graph for a controller outside Python, checked against it
  sweep       controllers over many plants with wide parameter ranges (local processes or Ray)

examples:
  millvib simulate --set c1=1.25e5 --kp 3.5e6 --plot run.png
  millvib reproduce --out results/paper
  millvib benchmark
  millvib benchmark --task rolling
  millvib headroom --task rolling
"""


def _add_plant_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="paper", help="plant preset in configs/plant/ or a YAML path (default: paper)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="NAME=VALUE",
                   help="override a plant parameter, e.g. --set c1=2.25e5 --set Ct=5e-9 (SI units; "
                        "'millvib params' lists them)")
    p.add_argument("--kp", type=float, default=1e5, help="proportional gain KP, V/m (default 1e5, the paper's)")
    p.add_argument("--ki", type=float, default=1e-3, help="integral gain KI, V/(m s) (default 1e-3)")
    p.add_argument("--kd", type=float, default=0.0, help="derivative gain KD, V s/m (default 0)")


def _cmd_simulate(args) -> int:
    from millvib_env._paths import check_output

    check_output(args.plot, "--plot")
    check_output(args.csv, "--csv")
    from millvib_env.params import PIDGains, load_preset, parse_overrides
    from millvib_env.plant.integrate import simulate
    from millvib_env.severity import severity_band

    params = load_preset(args.preset).replace(**parse_overrides(args.overrides))
    gains = PIDGains(args.kp, args.ki, args.kd)
    severity_band()  # configs/severity.yaml, checked before the run
    run = simulate(params, gains, args.t_end, x0=args.x0, xd=args.xd, method=args.method)
    from millvib_env.analysis.dynamics import classify_motion  # scipy.signal: after every input is checked

    motion = classify_motion(run)
    out = {"diverged": run.diverged, "status": run.status, "t_end_s": args.t_end, "method": args.method,
           "wall_s": run.info["wall_s"], "motion": motion.label}
    if run.diverged:
        out["t_diverged_s"] = run.t_diverged
    else:
        sev = run.severity()
        out.update({"severity_mm_s": sev, "iso_zone": run.iso_zone(), "tracking_rms_um": run.tracking_rms() * 1e6,
                    "tail_amplitude_um": motion.amplitude_m * 1e6, "tail_frequency_hz": motion.frequency_hz})
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for k, v in out.items():
            print(f"{k:>20}: {v:.6g}" if isinstance(v, float) else f"{k:>20}: {v}")
    if args.plot:
        _plot_run(run, Path(args.plot))
        print(f"wrote {args.plot}")
    if args.csv:
        _write_run_csv(run, Path(args.csv))
        print(f"wrote {args.csv}")
    return 0


def _plot_run(run, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from millvib_env._figures import panel_grid
    from millvib_env._paths import save_figure

    fig, ax, _ = panel_grid(2, 2, width=5.5, height=3.1, colorbar=False, suptitle=0.35,
                            margins=(0.75, 0.15, 0.55, 0.35))
    ax[0, 0].plot(run.t * 1e3, run.x * 1e3)
    ax[0, 0].set(xlabel="t (ms)", ylabel="x (mm)", title="displacement")
    ax[0, 1].plot(run.x * 1e3, run.v * 1e3, lw=0.7)
    ax[0, 1].set(xlabel="x (mm)", ylabel="v (mm/s)", title="phase portrait")
    ax[1, 0].plot(run.t * 1e3, run.pL / 1e6, label="pL")
    ax[1, 0].plot(run.t * 1e3, run.ps / 1e6, lw=0.5, label="ps(t)")
    ax[1, 0].set(xlabel="t (ms)", ylabel="MPa", title="chamber and supply pressure")
    ax[1, 0].legend()
    ax[1, 1].plot(run.t * 1e3, run.u)
    title_u = "valve command"
    if math.isfinite(run.params.u_max):  # the amplifier's range, which no command leaves
        for sign in (-1, 1):
            ax[1, 1].axhline(sign * run.params.u_max, color="k", ls="--", lw=0.8)
        title_u += f" (limit +-{run.params.u_max:g} V dashed)"
    ax[1, 1].set(xlabel="t (ms)", ylabel="u (V)", title=title_u)
    for a in ax.flat:
        a.grid(alpha=0.3)
    p = run.params
    title = f"c1={p.c1:.3g}, Ct={p.Ct:.3g}, KP={run.gains.kp:.3g}"
    if not run.diverged:
        title += f": severity {run.severity():.3g} mm/s (zone {run.iso_zone()})"
    fig.suptitle(title)
    save_figure(fig, path)


def _write_run_csv(run, path: Path) -> None:
    import numpy as np

    from millvib_env._paths import atomic_path

    names = ["t", "x", "v", "a", "pL", "z", "uI", "u", "xv", "QL", "Ff", "ps", "xd"]
    data = np.column_stack([getattr(run, n) for n in names])
    with atomic_path(path) as tmp:
        np.savetxt(tmp, data, delimiter=",", header=",".join(names), comments="")


def _cmd_reproduce(args) -> int:
    from millvib_env._paths import check_result_folder

    check_result_folder(args.out, "--out", "reproduce")
    from millvib_env.analysis.paper import reproduce

    summary = reproduce(args.out, t_end=args.t_end, method=args.method, maps=not args.no_maps,
                        map_resolution=args.resolution, progress=not args.quiet,
                        solver_study=not args.no_solver_study, solver_study_only=args.solver_study, jobs=args.jobs,
                        figures=not args.no_figures)
    if "table" in summary:
        print(summary["table"])
        print()
    if "solver_table" in summary:
        print("Tail (last 40 %) peak-to-peak displacement in um and kind of motion, per solver setting:\n")
        print(summary["solver_table"])
        print()
        for v in summary["solver_study"]["verdicts"]:
            print(f"{v['case']}: ode45 default {v['default_ptp_um']:.3g} um ({v['default_motion']}), converged "
                  f"{v['converged_ptp_um']:.3g} um ({v['converged_motion']}): {v['verdict']}")
        print()
    for c in summary.get("claims", []) if "table" in summary else []:
        verdict = "reproduced" if c["direction_reproduced"] else "NOT reproduced"
        print(f"{c['study']}: '{c['direction_claim']}': {verdict}; kind claimed: {c['kind_claim']}; "
              f"measured: {c['kinds_measured']}")
    print(f"\nwrote {len(summary['files'])} files to {args.out}")
    return 0


def _cmd_speed(args) -> int:
    from millvib_env._paths import check_output


    check_output(args.json, "--json")
    from millvib_env import speed

    result = {"plant": speed.bench_plant(t_end=args.t_end, repeats=args.repeats, batch_size=args.batch_size,
                                         progress=not args.quiet)}
    print(speed.format_plant_bench(result["plant"]))
    if not args.plant_only:
        env_res = speed.bench_envs(progress=not args.quiet)
        result["envs"] = env_res
        print()
        print(speed.format_env_bench(env_res))
    if args.json:
        speed.save_json(result, args.json)
        print(f"\nwrote {args.json}")
    if args.command == "bench":  # the earlier name, kept for one release
        print("note: millvib bench is now 'millvib speed' ('bench' stays for one release)", file=sys.stderr)
    return 0


def _cmd_params(args) -> int:
    from millvib_env.params import MillParams

    print(f"{'name':>10} {'default':>12} {'unit':>12}  meaning [allowed range]")
    for name, default, unit, doc, rule in MillParams.describe():
        print(f"{name:>10} {default:>12.6g} {unit:>12}  {doc} [{rule}]")
    return 0


def _cmd_scenarios(args) -> int:
    from millvib_env.envs.scenarios import format_scenarios

    print(format_scenarios(measure=not args.no_measure))
    return 0


def _cmd_tasks(args) -> int:
    from millvib_env.tasks import SEED_PURPOSES, all_tasks

    print("| task | env config | " + " | ".join(f"{p} seeds" for p in SEED_PURPOSES) + " | episode |")
    print("|---|---|" + "---|" * len(SEED_PURPOSES) + "---|")
    for t in all_tasks():
        spans = " | ".join(f"{t.seeds[p].start}-{t.seeds[p].stop - 1}" for p in SEED_PURPOSES)
        print(f"| {t.name} | {t.config} | {spans} | {t.description} |")
    return 0


def _cmd_train(args) -> int:
    from millvib_env.training.hyperparams import load_hyperparams

    load_hyperparams(args.algo, args.env, args.config)  # the files, refused before torch and SB3 load (seconds)
    from millvib_env.training.train import train_from_cli

    return train_from_cli(args)


def _cmd_sweep(args) -> int:
    from millvib_env.evaluation.sweep import sweep_from_cli

    return sweep_from_cli(args)


def _cmd_tune(args) -> int:
    from millvib_env.tuning.baselines import tune_from_cli

    return tune_from_cli(args)


def _cmd_export(args) -> int:
    from millvib_env._paths import check_output
    from millvib_env.catalog.export import export_agent

    check_output(args.out, "--out")
    summary = export_agent(args.agent, args.out, seed=args.seed, check_steps=args.check_steps,
                           latency_calls=args.latency_calls)
    print(json.dumps(summary, indent=2))
    print(f"wrote {args.out} (run it without torch: millvib benchmark --task {summary['task']} --controllers "
          f"{args.out})")
    return 0


def _cmd_distill(args) -> int:
    import sys

    from pathlib import Path

    from millvib_env._paths import agents_dir, check_result_folder
    from millvib_env.catalog.manifest import AGENT_FILES, write_manifest
    from millvib_env.training.distill import distill

    check_result_folder(args.save_dir, "--save-dir", "distill", own_files=AGENT_FILES)
    card = distill(args.task, teacher=args.teacher, baseline=args.baseline, seed=args.seed, iterations=args.iterations,
                   episodes=args.episodes, epochs=args.epochs, save_dir=args.save_dir, progress=not args.quiet,
                   net=tuple(args.net), range_v=args.range_v, history=tuple(args.history),
                   loop_sample=args.loop_sample, preview_gauge=args.preview, on=args.on,
                   command=" ".join(["millvib", *(a for a in sys.argv[1:] if a != "--resume")]),
                   validation_episodes=args.validation_episodes, budget=args.budget, filters=tuple(args.filters),
                   validate_from=args.validate_from, batch=args.batch, resume=args.resume)
    print(json.dumps({k: card[k] for k in ("name", "task", "seed", "trained_by", "validation", "selected")}, indent=2))
    if Path(agents_dir()).resolve() in Path(args.save_dir).resolve().parents:
        print(f"updated {write_manifest()}")
    print(f"wrote {args.save_dir}")
    return 0


def _cmd_finetune(args) -> int:
    from millvib_env.training.finetune import finetune_from_cli

    return finetune_from_cli(args)


def _cmd_headroom(args) -> int:
    from millvib_env.evaluation.benchmark import headroom_from_cli

    return headroom_from_cli(args)


def _cmd_benchmark(args) -> int:
    from millvib_env.evaluation.benchmark import benchmark_from_cli

    return benchmark_from_cli(args)


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (the flag, the value, what is allowed) and exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _plain(doc: str | None) -> str:
    """A module docstring as a command's help: its reST markup (``code``, `name`, :role:`name`) as plain text."""
    import re

    text = re.sub(r":[a-z]+:`([^`]+)`", r"\1", doc or "")
    text = re.sub(r"``([^`]+)``", r"\1", text)
    return re.sub(r"`([^`]+)`", r"\1", text)


def _module_doc(module: str) -> str:
    """A module's docstring, read from its source without running it: `tune`'s and `distill`'s modules load the
    controllers, a fifth of a second that every other command would pay for help texts it does not show."""
    import ast
    import importlib.util

    spec = importlib.util.find_spec(module)
    assert spec is not None and spec.origin is not None
    return ast.get_docstring(ast.parse(Path(spec.origin).read_text(encoding="utf-8")), clean=False) or ""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="millvib", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    from millvib_env import __version__

    parser.add_argument("--version", action="version", version=f"millvib-env {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="<command>")

    for add in (_add_simulate, _add_reproduce, _add_speed, _add_listings,
                _add_learning, _add_tune, _add_export, _add_distill, _add_finetune,
                _add_sweep):
        add(sub)
    return parser


def _add_simulate(sub) -> None:
    p = sub.add_parser("simulate", help="one closed-loop run", description=(
        "Simulate one closed-loop plant from the paper's initial state (x0 = 1 mm at rest) and print its "
        "vibration severity (mm/s RMS, 10-1000 Hz), ISO 20816-3 zone, kind of motion over the last 40 % of "
        "the run and RMS tracking error."))
    _add_plant_args(p)
    p.add_argument("--t-end", type=float, default=1.0, help="simulated time, s (default 1.0)")
    p.add_argument("--x0", type=float, default=1e-3, help="initial displacement, m (default 1e-3)")
    p.add_argument("--xd", type=float, default=0.0, help="set-point, m (default 0)")
    p.add_argument("--method", choices=["fast", "reference"], default="fast",
                   help="fast: compiled adaptive BS3(2); reference: LSODA (ODEPACK's, compiled) at rtol 1e-9")
    p.add_argument("--plot", metavar="PNG", help="write a figure of x, phase portrait, pressures and valve command")
    p.add_argument("--csv", metavar="CSV", help="write the sampled run (10 kHz) as CSV")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=_cmd_simulate)


def _add_reproduce(sub) -> None:
    p = sub.add_parser("reproduce", help="the paper's studies, figures and tables", description=(
        "Simulate the paper's nine cases (c1, Ct and KP studies), write the analogues of Figs. 4-9 (PNG), the "
        "numbers (CSV, JSON), a map of the kind of motion over (c1, KP) and the linear stability map, and print "
        "the table with a verdict per claim."))
    p.add_argument("--out", default="results/paper", help="output folder (default results/paper)")
    p.add_argument("--t-end", type=float, default=1.0, help="simulated time per case, s (default 1.0)")
    p.add_argument("--method", choices=["fast", "reference"], default="fast")
    p.add_argument("--no-maps", action="store_true", help="skip the motion and stability maps")
    p.add_argument("--solver-study", action="store_true",
                   help="only the solver study: the nine cases under ode45's default tolerances (RelTol 1e-3, "
                        "AbsTol 1e-6), Simulink's default max step and tighter tolerances down to the converged "
                        "reference; tail amplitude, frequency and kind of motion per run (CSV, figures, "
                        "summary.json's solver_study)")
    p.add_argument("--no-solver-study", action="store_true", help="skip the solver study in a full run")
    p.add_argument("--no-figures", action="store_true", help="write the numbers alone (CSV, summary.json), no PNG")
    p.add_argument("--resolution", type=int, default=14, help="grid points per axis of the maps (default 14)")
    p.add_argument("--jobs", type=int, default=1,
                   help="processes for the stability maps' cells and the solver study's runs (default 1; each is "
                        "independent, so the files are the same for any number)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_reproduce)


def _add_speed(sub) -> None:
    speed_description = (
        "Measure in one run: wall time per simulated second of LSODA at rtol 1e-6 (scipy's solve_ivp, and ODEPACK's "
        "run whole in compiled code, the reference's default) and the fast "
        "integrator on the paper's nine cases with the fast one's error against a tight reference; batched "
        "throughput over random plants (1 s each); and environment steps per second (native VecEnv vs SB3 "
        "DummyVecEnv). (Controllers are compared by 'millvib benchmark'.)")
    for name in ("speed", "bench"):  # bench: the earlier name, kept for one release and left out of the list
        if name == "speed":
            p = sub.add_parser(name, help="integrator and environment speed", description=speed_description)
        else:  # no help: argparse leaves it out of the list
            p = sub.add_parser(name, description=speed_description)
        p.add_argument("--t-end", type=float, default=1.0, help="simulated time per case, s (default 1.0)")
        p.add_argument("--repeats", type=int, default=5, help="timing repeats per case, median taken (default 5)")
        p.add_argument("--batch-size", type=int, default=256,
                       help="plants in the batched-throughput row (default 256)")
        p.add_argument("--plant-only", action="store_true", help="skip the environment benchmark")
        p.add_argument("--json", metavar="PATH", help="also write the results as JSON")
        p.add_argument("--quiet", action="store_true", help="no progress bars")
        p.set_defaults(func=_cmd_speed)


def _add_listings(sub) -> None:
    p = sub.add_parser("params", help="list the plant parameters", description=(
        "List every field of MillParams (paper Table 1 and the project's additions): symbol, default, unit, "
        "meaning and the allowed range; a value outside it raises a one-line error naming the field. "
        "Presets in configs/plant/ (paper.yaml is Table 1) set them; --set NAME=VALUE overrides one."))
    p.set_defaults(func=_cmd_params)

    p = sub.add_parser("scenarios", help="list the named failure scenarios", description=(
        "List the named scenarios (the paper's fixed-PID failure cases) with the paper PID's severity, ISO zone "
        "and tracking error, measured now."))
    p.add_argument("--no-measure", action="store_true", help="only list names and descriptions")
    p.set_defaults(func=_cmd_scenarios)

    p = sub.add_parser("tasks", help="the benchmark's tasks and their seed ranges", description=(
        "List the tasks (configs/tasks.yaml): each an environment config and four disjoint seed ranges for "
        "training, tuning, validation and the benchmark's held-out plants."))
    p.set_defaults(func=_cmd_tasks)


def _add_learning(sub) -> None:
    from millvib_env.evaluation.benchmark.flags import add_benchmark_args
    from millvib_env.training.cli_args import add_train_args

    add_train_args(sub.add_parser("train", help="train an agent", description=textwrap.fill(
        "Train a Stable-Baselines3 agent (SAC with sbx where installed) with the hyperparameters of a zoo-style "
        "YAML file for the env id: progress bar, TensorBoard logs, periodic evaluation, checkpoints, --resume, "
        "final model and VecNormalize statistics. --config picks the file: configs/agents/<algo>.yml by default "
        "(a gain schedule over the absolute gain bounds); configs/agents/pf/<algo>.yml is the shipped agents' "
        "(a relative action around pid-pf-robust, whose zero action is that controller), e.g.", 79) +
        "\n\n  millvib train --algo ppo --task rolling --config configs/agents/pf/ppo.yml --select best",
        formatter_class=argparse.RawDescriptionHelpFormatter), _cmd_train)
    add_benchmark_args(sub.add_parser("benchmark", help="controllers on held-out plants", description=(
        "Evaluate controllers (the baselines: pid-paper, pid-nominal, pid-robust, pid-oracle, pid-adaptive, "
        "lqr-oracle, pid-pf-robust, pid-pf-ff, pid-pf-oracle and, on v1, the MPC bounds mpc-oracle and mpc-preview; "
        "and agents) on the same held-out plants of a task (--task startup, rolling, change or varied) and, "
        "for startup, on every named scenario; report cost (mean and CVaR-20), severity (mean, p95, first "
        "0.1 s, rest, pump line, 10-100 Hz), ISO zones, tracking RMS and divergence. With no arguments: every "
        "baseline and every shipped agent of the startup task.")), _cmd_benchmark)
    add_benchmark_args(sub.add_parser("headroom", help="the room to learn on a task: classical controllers against "
                                      "the bounds", description=(
        "How much any controller could gain on a task of the loop as commissioned (v1): the deployable classical "
        "controllers (pid-paper, pid-nominal, pid-robust, pid-adaptive, pid-pf-robust, pid-pf-ff) and the bounds "
        "that know the plant (pid-pf-oracle: per-plant re-tuned PID + pressure feedback; lqr-oracle; mpc-oracle: "
        "model-predictive control of the valve with the plant's true state, within +-10 V; mpc-preview: the same "
        "with the disturbances' course over its horizon) on the same held-out plants. Prints the benchmark's "
        "table with the room: (reference - bound) / reference on the mean and the CVaR-20, with paired 95 % "
        "intervals, and each controller's share of it. --controllers adds or replaces rows.")), _cmd_headroom)


def _add_tune(sub) -> None:
    from millvib_env.tuning import ENTRIES

    p = sub.add_parser("tune", help="tune a task's classical baselines",
                       description=_plain(_module_doc("millvib_env.tuning.baselines")),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="startup", help="task: startup, rolling, change or varied (default startup)")
    p.add_argument("--only", nargs="+", choices=ENTRIES, metavar="ENTRY",
                   help=f"tune only these entries (default: all): {', '.join(ENTRIES)}")
    p.add_argument("--from", dest="from_task", metavar="TASK",
                   help="take pid-oracle, lqr-oracle and pid-pf-oracle from this task instead of tuning them")
    p.add_argument("--grid", type=int, default=5, help="oracle grid points per axis (default 5)")
    p.add_argument("--jobs", type=int, default=1,
                   help="worker processes for the oracle tables' grid plants (pid-oracle, pid-pf-oracle) and "
                        "pid-pf-preview's batches of gain sets (default 1); the results are the same for any number")
    p.add_argument("--env-version", default="v1", choices=["v0", "v1"],
                   help="the loop the gains are tuned on: v1, the loop as commissioned (default; written to "
                        "configs/control/v1/<task>.yaml), or v0, the paper's analog loop (configs/control/<task>.yaml)")
    p.add_argument("--optuna", metavar="STORAGE", help="tune pid-nominal and pid-robust by an Optuna study in "
                                                        "STORAGE (journal:PATH or a database URL), shared by every "
                                                        "process that names it")
    p.add_argument("--trials", type=int, default=60, help="Optuna trials this process runs (default 60)")
    p.add_argument("--out", metavar="FILE", help="write the task's control config with the tuned entries to FILE")
    p.add_argument("--write-config", action="store_true",
                   help="write into the shipped configs/control/[v1/]<task>.yaml instead")
    p.add_argument("--force", action="store_true",
                   help="replace entries even where this run's tuning cost is worse than theirs")
    p.add_argument("--resume", action="store_true", help="go on from an unfinished run's entries (FILE.partial)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=_cmd_tune)


def _add_export(sub) -> None:
    p = sub.add_parser("export", help="a trained agent as an ONNX graph, checked against the agent",
                       description=_plain(_module_doc("millvib_env.catalog.export")),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("agent", help="a shipped agent's name (millvib benchmark lists them) or an agent folder")
    p.add_argument("--seed", type=int, default=None, help="the training seed of a multi-seed agent (default: "
                                                          "its lowest)")
    p.add_argument("--out", required=True, metavar="FILE", help="the .onnx file to write")
    p.add_argument("--check-steps", type=int, default=400,
                   help="observations of one of the task's episodes on which the graph must act as the agent "
                        "(default 400)")
    p.add_argument("--latency-calls", type=int, default=2000,
                   help="calls timed at batch 1 for the figure printed (default 2000; 0: none)")
    p.set_defaults(func=_cmd_export)


def _add_distill(sub) -> None:
    from millvib_env.training.cli_args import add_distill_args

    add_distill_args(sub.add_parser("distill", help="teach a residual valve policy with a preview by the MPC oracle",
                       description=_plain(_module_doc("millvib_env.training.distill")),
                       formatter_class=argparse.RawDescriptionHelpFormatter), _cmd_distill)


def _add_finetune(sub) -> None:
    from millvib_env.training.cli_args import add_finetune_args

    add_finetune_args(sub.add_parser("finetune", help="PPO on top of a distilled student, stopped on validation plants",
                                     description=_plain(_module_doc("millvib_env.training.finetune")),
                                     formatter_class=argparse.RawDescriptionHelpFormatter), _cmd_finetune)


def _add_sweep(sub) -> None:
    p = sub.add_parser("sweep", help="controllers over many plants", description=(
        "A robustness sweep: every controller on N plants of a task with the swept parameters drawn over wide "
        "ranges (c1, Ct: the paper's, log-uniform; beta_e, mt, FL: +-20 % of Table 1), from held-out seeds. Writes "
        "plants.csv, summary.json and maps.png to --out. Runs in local processes (--jobs) or on Ray (--ray)."))
    p.add_argument("--controllers", nargs="+", required=True, help="baselines or agents, as for benchmark")
    p.add_argument("--plants", type=int, required=True, help="number of plants (episodes per controller)")
    p.add_argument("--params", nargs="+", default=["c1", "Ct"], metavar="NAME",
                   help="parameters to sweep: c1 Ct beta_e mt FL (default c1 Ct)")
    p.add_argument("--task", default="startup", help="task (default startup)")
    p.add_argument("--env-version", default="v1", choices=["v0", "v1"],
                   help="the loop the baselines run on: v1, as commissioned (default), or v0, the paper's analog loop")
    p.add_argument("--seed", type=int, default=None, help="first plant seed (default: 40000 into its held-out range)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (replaced as a whole)")
    p.add_argument("--no-figures", action="store_true", help="write plants.csv and summary.json only, not maps.png")
    p.add_argument("--jobs", type=int, default=1, help="local processes (default 1)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="run on Ray: a local cluster, or the running cluster at ADDRESS")
    p.add_argument("--resume", action="store_true", help="go on from an unfinished run's jobs (DIR.partial)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_sweep)

def main(argv: list[str] | None = None) -> int:
    """Run one `millvib` command; the exit status is returned, never raised (`millvib_cli` exits with it)."""
    previous = _interrupt.install()  # SIGINT and SIGTERM recorded before they raise (`_interrupt`)
    try:
        return _run(argv)
    finally:
        _interrupt.restore(previous)


def _close_bars() -> None:
    """Close the progress bars a run left open (tqdm's instances), so the run's last line is printed below them,
    not drawn over by a bar that is closed later."""
    tqdm_module = sys.modules.get("tqdm")
    if tqdm_module is not None:
        for bar in list(getattr(tqdm_module.tqdm, "_instances", ())):
            bar.close()


def _run(argv: list[str] | None) -> int:
    command = "millvib"
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 0
        command = f"millvib {args.command}"
        if getattr(args, "task", None) is not None:  # a task's name enters here, and a `Task` goes on
            from millvib_env.tasks import get_task

            args.task = get_task(args.task)
        status = int(args.func(args) or 0)
        _interrupt.check()  # a signal a library swallowed: the command did not finish
        return status
    except _interrupt.Terminated:
        return _signalled(command, signal.SIGTERM)
    except KeyboardInterrupt:
        return _signalled(command, signal.SIGINT)
    except Exception as err:
        if _interrupt.pending():  # a library turned the signal into its own error (numba: a SystemError)
            return _signalled(command, _interrupt.pending())
        _close_bars()
        if isinstance(err, ValueError):
            print(f"{command}: error: {err}", file=sys.stderr)
            return 2
        if isinstance(err, OSError):  # a full disk, a read-only or forbidden folder met while writing: one line, 2
            where = f": {err.filename}" if err.filename else ""
            print(f"{command}: error: {err.strerror or err}{where}", file=sys.stderr)
            return 2
        raise


def _signalled(command: str, signum: int) -> int:
    """The one line and the status of a run that a signal ended (SIGTERM: 143, Ctrl-C: 130)."""
    _close_bars()
    said = f"; {note}" if (note := _interrupt.take_note()) else ""
    if signum == signal.SIGTERM:
        print(f"{command}: terminated{said}", file=sys.stderr)
        return 143
    print(f"{command}: interrupted{said}", file=sys.stderr)
    return 130


if __name__ == "__main__":
    sys.exit(main())
