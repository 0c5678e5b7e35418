"""A benchmark's result as text: the markdown tables (`format_table`) and the JSON it writes (`public_json`)."""

from __future__ import annotations

import math

from millvib_env.evaluation.verdict import format_information
from millvib_env.evaluation.benchmark.comparison import format_room


def _ci(s: dict, key: str, fmt: str = ".3g") -> str:
    lo, hi = s[f"{key}_ci"]
    return f"{s[key]:{fmt}} [{lo:{fmt}}, {hi:{fmt}}]"


def format_table(result: dict) -> str:
    ctrls = result["controllers"]
    seeds_line = ("every training seed of every agent (the full protocol, --all-seeds)" if result.get("all_seeds")
                  else "one training seed per agent (its lowest; the full protocol is --all-seeds)")
    ref = result.get("reference", "pid-robust")
    lines = [f"Task {result.get('task', 'startup')}: {result['episodes']} held-out plants drawn with seed "
             f"{result['seed']}; {seeds_line}. Cost = severity / {result['cost_scales']['severity_mm_s']} mm/s + "
             f"tracking RMS / {result['cost_scales']['tracking_um']} um; IQM = mean of the middle 50 % of episodes; "
             "CVaR-20 = mean of the worst 20 %; [95 % bootstrap intervals: plants resampled within each training "
             f"seed; paired to the reference {ref} (and to pid-robust) on the same plants]. The normalised score "
             "(0 = pid-robust, 1 = pid-oracle) is in the JSON only: where the two cost nearly the same it is "
             "ill-conditioned",
             "",
             f"| controller | seeds | cost mean | cost IQM | cost CVaR-20 | worst episode | vs {ref} | "
             f"CVaR-20 vs {ref} | P(better than {ref}) | vs pid-robust | severity (mm/s) | "
             "tracking RMS (um) | diverged |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    if result.get("title"):  # another command's table (the sweep) names its own plants
        lines[0] = result["title"]

    def pct(d: dict | None, key: str, ci: str) -> str:
        return f"{100 * d[key]:+.1f} % [{100 * d[ci][0]:+.1f}, {100 * d[ci][1]:+.1f}]" if d else "-"

    for name, s in ctrls.items():
        pr = s.get("paired", {}).get(ref)
        robust = s.get("paired", {}).get("pid-robust")
        pb = f"{pr['p_improvement']:.2f}" if pr else "-"
        lines.append(f"| {name} | {s['n_seeds']} | {_ci(s, 'cost_mean')} | {_ci(s, 'cost_iqm')} | "
                     f"{_ci(s, 'cost_cvar20')} | {_ci(s, 'cost_worst')} | {pct(pr, 'cost_diff_rel', 'ci')} | "
                     f"{pct(pr, 'cvar20_diff_rel', 'cvar20_ci')} | {pb} | {pct(robust, 'cost_diff_rel', 'ci')} | "
                     f"{_ci(s, 'severity_mean')} | {_ci(s, 'tracking_rms_um_mean')} | "
                     f"{100 * s['diverged_rate']:.0f} % |")
    oracle = ctrls.get("pid-oracle", {}).get("normalized_score")
    if oracle and oracle.get("one_worse_than_zero"):
        lines.append("\nOn this task pid-oracle (the per-plant best fixed PID) costs more on average than pid-robust, "
                     "so the JSON's normalised score runs the other way: below 0 is better than pid-robust.")
    room_md = format_room(result)
    info_md = format_information(result)
    if info_md:
        room_md = (room_md + "\n\n" + info_md) if room_md else info_md
    if room_md:
        lines += ["", room_md]
    lines += _vibration_rows(ctrls) + _actuator_rows(result) + _spread_rows(ctrls) + _estimate_rows(ctrls)
    lines += _scenario_rows(result)
    return "\n".join(lines)


def _vibration_rows(ctrls: dict) -> list[str]:
    """The table's vibration detail: severity quantiles, where in the episode, the bands, ISO zones."""
    lines: list[str] = []
    lines += ["", "Vibration detail (pooled episodes):", "",
              "| controller | severity median | p95 | first 0.1 s | rest | pump line | 10-100 Hz | zones A/B/C/D |",
              "|---|---|---|---|---|---|---|---|"]
    for name, s in ctrls.items():
        z = s["iso_zones"]
        lines.append(f"| {name} | {s['severity_median']:.3g} | {s['severity_p95']:.3g} | "
                     f"{s.get('severity_start_mean', math.nan):.3g} | {s.get('severity_rest_mean', math.nan):.3g} | "
                     f"{s.get('pump_line_mean', math.nan):.3g} | {s.get('low_band_mean', math.nan):.3g} | "
                     f"{z['A']}/{z['B']}/{z['C']}/{z['D']} |")
    return lines


def _actuator_rows(result: dict) -> list[str]:
    """The actuator's table (where every controller has its command record)."""
    ctrls = result["controllers"]
    lines: list[str] = []
    if all("command" in s for s in ctrls.values()):
        loop = result.get("loop") or {}
        u_max = loop.get("u_max_v")
        lines += ["", f"The actuator ({result.get('env_version', 'v0')}: "
                  + (f"a {loop.get('rate_hz', 0):g} Hz digital loop, " if loop.get("kind") == "digital" else
                     "the paper's analog loop, ")
                  + (f"amplifier limit +-{u_max:g} V" if u_max is not None else "no amplifier limit")
                  + "; per episode, median / p95 / max over the episodes):", "",
                  "| controller | largest command (V) | time at the limit | spool stroke (mm) | peak flow / rated flow "
                  "| chamber pressure (MPa) | diverged episodes |", "|---|---|---|---|---|---|---|"]
        for name, s in ctrls.items():
            c, st, fl, pr = s["command"]["max_abs_v"], s["spool_stroke_m"], s["peak_flow_ratio"], s["pressure_pa"]
            lines.append(f"| {name} | {c['median']:.3g} / {c['p95']:.3g} / {c['max']:.3g} | "
                         f"{100 * s['command']['share_at_limit']:.1f} % | {1e3 * st['median']:.3g} / "
                         f"{1e3 * st['p95']:.3g} / {1e3 * st['max']:.3g} | {fl['median']:.3g} / {fl['p95']:.3g} / "
                         f"{fl['max']:.3g} | {pr['min'] / 1e6:.3g}-{pr['max'] / 1e6:.3g} | {s['n_diverged']} |")
    return lines


def _spread_rows(ctrls: dict) -> list[str]:
    """Each multi-seed agent's mean cost and CVaR-20 per training seed."""
    lines: list[str] = []
    spread = {n: s["per_seed"] for n, s in ctrls.items() if len(s.get("per_seed", [])) > 1}
    if spread:
        lines += ["", "Spread over training seeds (mean cost / CVaR-20 of each seed on the same plants):", "",
                  "| agent | per seed | range of the means |", "|---|---|---|"]
        for name, per in spread.items():
            cells = ", ".join(f"s{p['seed']}: {p['cost_mean']:.3g} / {p['cost_cvar20']:.3g}" for p in per)
            means = [p["cost_mean"] for p in per]
            lines.append(f"| {name} | {cells} | {min(means):.3g}-{max(means):.3g} |")
    return lines


def _estimate_rows(ctrls: dict) -> list[str]:
    """The estimation error of the controllers that estimate the plant (pid-adaptive)."""
    lines: list[str] = []
    est = {n: s for n, s in ctrls.items() if "c1_log_error_mean" in s}
    for name, s in est.items():
        lines.append(f"\n{name}: mean estimation error over the episodes |log10(estimate / true)|: c1 "
                     f"{s['c1_log_error_mean']:.3f}, Ct {s['ct_log_error_mean']:.3f} (decades)")
    return lines


def _scenario_rows(result: dict) -> list[str]:
    """The named scenarios' table: severity and tracking per scenario and controller."""
    lines: list[str] = []
    if result.get("scenarios"):
        names = list(result["scenarios"])
        scen = list(next(iter(result["scenarios"].values())))
        lines += ["", "Named scenarios with distinct plants, one episode each (severity mm/s / tracking RMS um):", "",
                  "| scenario | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for sc in scen:
            cells = []
            for n in names:
                r = result["scenarios"][n][sc]
                cells.append(("diverged " if r["diverged"] else "") + f"{r['severity_mm_s']:.3g} / "
                             f"{r['tracking_rms_um']:.3g}")
            lines.append(f"| {sc} | " + " | ".join(cells) + " |")
    return lines


def public_json(result: dict) -> dict:
    """The summary without the per-episode records (those go to the CSV), the controllers' specs and timings, so
    the same inputs give the same bytes."""
    return {k: v for k, v in result.items() if k not in ("records", "wall_time_s", "specs")}
