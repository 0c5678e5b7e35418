"""The ablation of the action design: the earlier agents (absolute gain action, residual on pid-robust;
results kept in docs/ablations/absolute-action/<task>/, written by `millvib benchmark --task T
--all-seeds --out docs/benchmark/T` at commit 6fe162e, before they were retired) beside today's (relative
action around pid-pf-robust, residual on pid-pf-ff; docs/benchmark/v0/<task>/), on the same 200 held-out
plants (both runs drew them with seed 0).

    python scripts/ablation_table.py
"""
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _row(task: str, name: str, s: dict, design: str) -> str:
    pr = s.get("paired_vs_pid_robust")
    vs = f"{100 * pr['cost_diff_rel']:+.1f} % [{100 * pr['ci'][0]:+.1f}, {100 * pr['ci'][1]:+.1f}]" if pr else "-"
    return (f"| {task} | {name} | {design} | {s['n_seeds']} | {s['cost_mean']:.3g} [{s['cost_mean_ci'][0]:.3g}, "
            f"{s['cost_mean_ci'][1]:.3g}] | {s['cost_cvar20']:.3g} | {vs} |")


def main() -> None:
    print("| task | agent | action design | seeds | cost mean | cost CVaR-20 | vs pid-robust (paired) |")
    print("|---|---|---|---|---|---|---|")
    for task in ("startup", "rolling", "change"):
        old = json.loads((ROOT / "docs" / "ablations" / "absolute-action" / task / "benchmark.json").read_text())
        new = json.loads((ROOT / "docs" / "benchmark" / "v0" / task / "benchmark.json").read_text())
        assert old["plants"] == new["plants"], f"{task}: the two runs met different plants"
        for name, s in old["controllers"].items():
            if "gain" in name or "residual" in name:
                design = "residual on pid-robust" if "residual" in name else "absolute (log ranges 3-11 decades wide)"
                print(_row(task, name, s, design))
        for name, s in new["controllers"].items():
            if not name.startswith("pid-") and not name.startswith("lqr-"):
                design = "residual on pid-pf-ff" if "residual" in name else "relative to pid-pf-robust"
                print(_row(task, name, s, design))


if __name__ == "__main__":
    main()
