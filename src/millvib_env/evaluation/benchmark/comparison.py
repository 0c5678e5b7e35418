"""The room to learn and the paired comparisons: each controller against the reference and `COMPARED_WITH` on the same
plants (`_compare`, computed as each controller's last episodes come in: `_Early`), and the room a bound leaves above
the deployable classical controllers (`room`, `format_room`)."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from millvib_env.catalog.registry import REGISTRY
from millvib_env.evaluation.stats import normalized_score, paired_difference
from millvib_env.evaluation.benchmark.lineup import DEPLOYABLE_CLASSICAL, ROOM_BOUNDS
from millvib_env.evaluation.benchmark.protocol import _by_seed, summarize


#: a room below this share of the reference's cost is reported as such, without shares (a ratio to a room of
#: a few tenths of a percent is noise over noise)
ROOM_THRESHOLD = 0.03


def room(result: dict) -> dict | None:
    """The room to learn on the benchmark's plants (`result["room"]`): for each bound of `ROOM_BOUNDS` that ran,
    room = (reference - bound) / reference on the mean and on the CVaR-20 with its paired 95 % interval; the
    room without preview is the largest of the bounds that know only the present (a lower bound on what a
    controller of any structure could gain: a better oracle would show more), the room with preview
    mpc-preview's. Where a room is at least `ROOM_THRESHOLD`, every controller's share of it: its mean improvement
    over the reference divided by the bound's (`stats.normalized_score` against the reference and the bound, with
    its interval), and the same ratio on the CVaR-20 (where that room is positive). The best deployable
    classical controller is named."""
    recs_of, ctrls = result["records"], result["controllers"]
    ref = result.get("reference")
    if ref not in recs_of:
        return None
    bounds = {}
    for name in ROOM_BOUNDS:
        pr = ctrls.get(name, {}).get("paired", {}).get(ref)
        if pr is None:
            continue
        bounds[name] = {"what": ROOM_BOUNDS[name], "room_mean": -pr["cost_diff_rel"],
                        "room_mean_ci": [-pr["ci"][1], -pr["ci"][0]], "room_cvar20": -pr["cvar20_diff_rel"],
                        "room_cvar20_ci": [-pr["cvar20_ci"][1], -pr["cvar20_ci"][0]]}
    if not bounds:
        return None
    present = [n for n in bounds if not REGISTRY[n].previews]
    previews = [n for n in bounds if REGISTRY[n].previews]
    rooms = {}
    if present:
        rooms["without_preview"] = max(present, key=lambda n: bounds[n]["room_mean"])
    if previews:
        rooms["with_preview"] = max(previews, key=lambda n: bounds[n]["room_mean"])
    ref_cost = [r["cost"] for r in recs_of[ref]]
    shares: dict = {}
    for name, recs in recs_of.items():
        if name == ref:
            continue
        costs = [[r["cost"] for r in g] for g in _by_seed(recs)]
        pr = ctrls[name]["paired"][ref]
        shares[name] = {}
        for which, bound in rooms.items():
            b = bounds[bound]
            if b["room_mean"] < ROOM_THRESHOLD:
                continue
            entry: dict = {"bound": bound,
                           "mean": normalized_score(costs, ref_cost, [r["cost"] for r in recs_of[bound]])}
            if b["room_cvar20"] > 0:
                entry["cvar20"] = -pr["cvar20_diff_rel"] / b["room_cvar20"]
            shares[name][which] = entry
    deployable = [n for n in DEPLOYABLE_CLASSICAL if n in ctrls]
    best = min(deployable, key=lambda n: ctrls[n]["cost_mean"]) if deployable else None
    return {"reference": ref, "bounds": bounds, "rooms": rooms, "shares": shares, "best_deployable_classical": best}


def format_room(result: dict) -> str:
    """The room's table (`room`), in markdown; empty where no bound ran."""
    r = result.get("room")
    if not r:
        return ""
    ref = r["reference"]
    pct = lambda v: f"{100 * v:+.1f} %"  # noqa: E731
    lines = [f"The room to learn (against {ref}; room = ({ref} - bound) / {ref}, paired 95 % intervals; a bound "
             "that costs more than the reference gives a negative room):", "",
             "| bound | what it knows | room, mean | room, CVaR-20 |", "|---|---|---|---|"]
    for name, b in r["bounds"].items():
        lines.append(f"| {name} | {b['what']} | {pct(b['room_mean'])} [{pct(b['room_mean_ci'][0])}, "
                     f"{pct(b['room_mean_ci'][1])}] | {pct(b['room_cvar20'])} [{pct(b['room_cvar20_ci'][0])}, "
                     f"{pct(b['room_cvar20_ci'][1])}] |")
    for which, bound in r["rooms"].items():
        b = r["bounds"][bound]
        lines.append(f"\nRoom {which.replace('_', ' ')}: {pct(b['room_mean'])} of the mean "
                     f"[{pct(b['room_mean_ci'][0])}, {pct(b['room_mean_ci'][1])}] ({bound})"
                     + (f": below {100 * ROOM_THRESHOLD:.0f} %. None of the controllers that know the plant and only "
                        "its present (per-plant tuning, LQR, MPC with the true state) finds much to gain here; a "
                        "better bound could show more"
                        if which == "without_preview" and b["room_mean"] < ROOM_THRESHOLD else ""))
    if r.get("best_deployable_classical"):
        lines.append(f"\nBest deployable classical controller: {r['best_deployable_classical']}.")
    heads = [h for h, bound in r["rooms"].items() if r["bounds"][bound]["room_mean"] >= ROOM_THRESHOLD]
    if r["shares"] and heads:
        lines += ["", "Share of the room each controller captures (its improvement over the reference / the bound's; "
                  "mean [interval] and CVaR-20):", "",
                  "| controller | " + " | ".join(f"share {h.replace('_', ' ')}" for h in heads) + " |",
                  "|---|" + "---|" * len(heads)]
        for name, sh in r["shares"].items():
            cells = []
            for h in heads:
                e = sh.get(h, {})
                m = e.get("mean")
                cell = (f"{m['score']:+.2f} [{m['ci'][0]:+.2f}, {m['ci'][1]:+.2f}]" if m else "-")
                cell += f" / {e['cvar20']:+.2f}" if "cvar20" in e else " / -"
                cells.append(cell)
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _comparisons(name: str, recs: list, recs_of: Mapping[str, list], reference: str | None) -> dict:
    """`name`'s paired comparisons on the same plants (`_compare`), from the records of those it is compared with
    (`recs_of`: at least the reference, pid-robust and pid-oracle, where they run)."""
    out: dict[str, Any] = {}
    refs = [n for n in dict.fromkeys([reference, "pid-robust"]) if n is not None and n in recs_of]
    costs = [[r["cost"] for r in g] for g in _by_seed(recs)]
    out["paired"] = {ref: paired_difference(costs, [r["cost"] for r in recs_of[ref]]) for ref in refs if ref != name}
    ref = recs_of.get("pid-robust")
    oracle = recs_of.get("pid-oracle")
    if ref is None:
        return out
    stable = {r["seed"] for r in ref if not r["diverged"]}
    out["diverged_where_pid_robust_stable"] = int(sum(r["diverged"] and r["seed"] in stable for r in recs))
    if name != "pid-robust":
        out["paired_vs_pid_robust"] = out["paired"]["pid-robust"]
    if oracle is not None:
        out["normalized_score"] = normalized_score(costs, [r["cost"] for r in ref], [r["cost"] for r in oracle])
    return out


#: the controllers every other is compared with, where they run (`_comparisons`; `Baseline.compared_with`)
COMPARED_WITH = tuple(name for name, b in REGISTRY.items() if b.compared_with)


def _compare(result: dict, done: Mapping[str, dict] | None = None) -> None:
    """Paired comparisons on the same plants: per controller `paired` = {reference: ..., "pid-robust":
    ...} (mean and CVaR-20 cost differences with their intervals, P(better)), `paired_vs_pid_robust`
    (the same as paired["pid-robust"], kept for earlier readers) and the normalised score
    (0 = pid-robust, 1 = pid-oracle). `done`: those already made, by controller (`_Early`)."""
    for name, recs in result["records"].items():
        result["controllers"][name].update(done[name] if done and name in done else
                                           _comparisons(name, recs, result["records"], result.get("reference")))


class _Early:
    """A benchmark's summaries and paired comparisons made while its jobs run (`_collect_records`'s `complete`):
    each controller's summary as soon as its last episodes come in, and its comparisons once those it is compared
    with (`COMPARED_WITH` and the reference, where they run) have come in too. The same calls on the same records as
    after the run, so the same numbers."""

    def __init__(self, names: Sequence[str], reference: str):
        self.reference = reference
        self.needed = {reference, *COMPARED_WITH} & set(names)
        self.records: dict[str, list] = {}
        self.summaries: dict[str, dict] = {}
        self.comparisons: dict[str, dict] = {}

    def __call__(self, name: str, recs: list) -> None:
        self.records[name] = recs
        self.summaries[name] = summarize(recs)
        if self.needed <= self.records.keys():
            for n, r in self.records.items():
                if n not in self.comparisons:
                    self.comparisons[n] = _comparisons(n, r, self.records, self.reference)
