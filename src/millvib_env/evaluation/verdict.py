"""Same information, same footing: each controller of a benchmark against the strongest classical controller that
reads the same signals, each information set's bound and its room, and the verdict on severity beside the cost's.

For every information set among the benchmark's deployable controllers (`catalog.information`):

* **its classical controller**: the cheapest (mean cost on the benchmark's plants) of the deployable baselines whose
  set lies within it (they read it, or less: every classical design open to a controller of the set, so what the
  set's controllers must at least beat); choosing on the same plants favours the classical side, never the learned
  one;
* **its bound**: the cheapest oracle that knows at least the set and, beyond it, only the plant and the
  disturbances now (`catalog.information.bound_candidates`); its room is ``(classical - bound) / classical`` on
  the mean and the CVaR-20, with paired 95 % intervals;
* **whether the bound holds**: no controller of the set costs less than it on the mean or on the CVaR-20 with an
  interval that excludes zero; the controllers that do are named (`beaten_by`): there the bound is not one.

For every controller, against its set's classical controller (`same_information`): the paired cost difference
(mean and CVaR-20), the paired severity difference (the mission's own metric) and the tracking RMS's, and the
tracking guard: a controller whose severity is lower but whose tracking RMS is more than `TRACKING_GUARD` higher
buys its vibration with thickness, and is flagged.
"""

from __future__ import annotations

from typing import Any, Mapping

from millvib_env.catalog.information import bound_candidates, classical_candidates, is_oracle
from millvib_env.evaluation.stats import paired_difference

__all__ = ["TRACKING_GUARD", "information_verdict", "format_information"]

#: the tracking RMS a controller may lose (relative, on the mean) while it gains severity, before it is flagged
TRACKING_GUARD = 0.10


def _groups(recs: list, key: str) -> list[list[float]]:
    """A controller's values of `key`, one list per training seed (in its records' order)."""
    by: dict[Any, list[float]] = {}
    for r in recs:
        by.setdefault(r.get("agent_seed"), []).append(float(r[key]))
    return list(by.values())


def _paired(recs: list, ref: list, key: str) -> dict:
    """`stats.paired_difference` of `key` between a controller's records and a reference's on the same plants."""
    return paired_difference(_groups(recs, key), [float(r[key]) for r in ref])


def _beats(d: dict) -> bool:
    """A paired difference whose mean or CVaR-20 interval lies wholly below zero."""
    return d["ci"][1] < 0 or d["cvar20_ci"][1] < 0


def information_verdict(result: Mapping[str, Any], sets: Mapping[str, str], baselines: set[str]) -> dict:
    """The verdict of a benchmark's `result` (its records and summaries) given each controller's information set
    (`sets`: name -> set) and which of them are baselines (the classical side): see the module docstring."""
    recs_of, ctrls = result["records"], result["controllers"]
    sets = {n: s for n, s in sets.items() if n in recs_of}
    classical_sets = {n: s for n, s in sets.items() if n in baselines}
    oracle_sets = {n: s for n, s in sets.items() if is_oracle(s)}
    out: dict[str, Any] = {}
    for target in sorted({s for s in sets.values() if not is_oracle(s)}, key=lambda s: (len(s.split("+")), s)):
        members = [n for n, s in sets.items() if s == target]
        cands = classical_candidates(target, classical_sets)
        classical = min(cands, key=lambda n: ctrls[n]["cost_mean"]) if cands else None
        bounds = bound_candidates(target, oracle_sets)
        bound = min(bounds, key=lambda n: ctrls[n]["cost_mean"]) if bounds else None
        entry: dict[str, Any] = {"members": members, "classical": classical, "classical_candidates": cands,
                                 "bound": bound}
        if classical is not None and bound is not None:
            d = _paired(recs_of[bound], recs_of[classical], "cost")
            entry["room_mean"], entry["room_mean_ci"] = -d["cost_diff_rel"], [-d["ci"][1], -d["ci"][0]]
            entry["room_cvar20"], entry["room_cvar20_ci"] = -d["cvar20_diff_rel"], [-d["cvar20_ci"][1],
                                                                                     -d["cvar20_ci"][0]]
        if bound is not None:
            beaten = [n for n in members if _beats(_paired(recs_of[n], recs_of[bound], "cost"))]
            entry["bound_holds"], entry["beaten_by"] = not beaten, beaten
        out[target] = entry
    for name, s in sets.items():
        if is_oracle(s) or s not in out or out[s]["classical"] in (None, name):
            continue
        ref = recs_of[out[s]["classical"]]
        cost, sev, trk = (_paired(recs_of[name], ref, k) for k in ("cost", "severity_mm_s", "tracking_rms_um"))
        ctrls[name]["same_information"] = {
            "classical": out[s]["classical"], "cost": cost, "severity": sev, "tracking": trk,
            "tracking_flag": bool(sev["cost_diff_rel"] < 0 and trk["cost_diff_rel"] > TRACKING_GUARD)}
    for name, s in sets.items():
        ctrls[name]["information"] = s
    return out


def _pct(v: float) -> str:
    return f"{100 * v:+.1f} %"


def _ci(d: dict, key: str = "cost_diff_rel", ci: str = "ci") -> str:
    return f"{_pct(d[key])} [{_pct(d[ci][0])}, {_pct(d[ci][1])}]"


def format_information(result: Mapping[str, Any]) -> str:
    """The verdict's two tables (`information_verdict`), in markdown; empty where it was not made."""
    info = result.get("information")
    if not info:
        return ""
    ctrls = result["controllers"]
    lines = ["Same information, same footing: each information set's classical controller (the cheapest deployable "
             "baseline that reads it or less), "
             "its bound (the cheapest oracle that knows it and, beyond it, only the plant "
             "and the disturbances now) and the room between them, (classical - bound) / classical, paired 95 % "
             "intervals:", "",
             "| information | classical | bound | room, mean | room, CVaR-20 | bound holds |",
             "|---|---|---|---|---|---|"]
    for target, e in info.items():
        room = (f"{_pct(e['room_mean'])} [{_pct(e['room_mean_ci'][0])}, {_pct(e['room_mean_ci'][1])}]",
                f"{_pct(e['room_cvar20'])} [{_pct(e['room_cvar20_ci'][0])}, {_pct(e['room_cvar20_ci'][1])}]") \
            if "room_mean" in e else ("-", "-")
        holds = "-" if "bound_holds" not in e else ("yes" if e["bound_holds"] else
                                                       "no: beaten by " + ", ".join(e["beaten_by"]))
        lines.append(f"| {target} | {e['classical'] or '-'} | {e['bound'] or '-'} | {room[0]} | {room[1]} | {holds} |")
    rows = [(n, c["same_information"]) for n, c in ctrls.items() if "same_information" in c]
    if rows:
        lines += ["", "Each controller against the classical controller of its own information (paired, negative = "
                  f"cheaper; severity is the mission's metric; flagged: lower severity bought with more than "
                  f"{100 * TRACKING_GUARD:.0f} % more tracking error):", "",
                  "| controller | information | against | cost, mean | cost, CVaR-20 | severity, mean | tracking RMS, "
                  "mean | flag |", "|---|---|---|---|---|---|---|---|"]
        for n, v in rows:
            lines.append(f"| {n} | {ctrls[n]['information']} | {v['classical']} | {_ci(v['cost'])} | "
                         f"{_ci(v['cost'], 'cvar20_diff_rel', 'cvar20_ci')} | {_ci(v['severity'])} | "
                         f"{_ci(v['tracking'])} | {'tracking' if v['tracking_flag'] else ''} |")
    return "\n".join(lines)
