"""Where in the `startup` episode a controller sits at the amplifier's limit: the share of the episode's command
samples at +-u_max during the set-point's ramp (until it reaches 0) and after it (the gauge and force steps).

    python scripts/saturation_phases.py [--controller pid-pf-robust] [--episodes 200]

On the benchmark's held-out plants (seed 0), one plant-trace per episode (`evaluation.evaluate.trace_episode`).
"""
import argparse

import numpy as np

from millvib_env.catalog.factory import load_controller
from millvib_env.tasks import get_task
from millvib_env.evaluation.evaluate import trace_episode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="pid-pf-robust")
    ap.add_argument("--episodes", type=int, default=200)
    args = ap.parse_args()
    t = get_task("startup")
    cfg = t.configs["v1"]
    u_max = cfg.base_params.u_max
    ramp_s = abs(cfg.initial.x0_m) / cfg.initial.setpoint_ramp_m_s
    ctrl = load_controller(args.controller, t, version="v1")
    ramp = after = total = 0
    for seed in t.heldout_plants(args.episodes, 0):
        tr = trace_episode(ctrl, seed=seed, task=t)  # a preview reader would see the exact preview here
        at = np.abs(tr["u"][1:]) >= u_max * (1 - 1e-9)
        during = tr["t"][1:] < ramp_s
        ramp += int(np.sum(at & during))
        after += int(np.sum(at & ~during))
        total += at.size
    share = 100 * (ramp + after) / total
    print(f"{args.controller} on {args.episodes} startup plants: at +-{u_max:g} V for {share:.1f} % of the episode: "
          f"{100 * ramp / total:.1f} % during the {1e3 * ramp_s:.0f} ms ramp, "
          f"{100 * after / total:.1f} % after it")


if __name__ == "__main__":
    main()
