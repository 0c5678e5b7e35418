"""Where a controller's tracking error lies in frequency: the RMS of e = xd - x (um) over the first validation
plants of a task, whole and per band, for each controller named (a baseline, a shipped agent or a folder).

    MILLVIB_NUM_THREADS=1 python scripts/tracking_bands.py --task rolling pid-pf-robust mpc-preview \
        dagger-residual-preview-rolling [--episodes 8] [--plot traces.png]

The bands' RMS come from Welch's estimate (scipy, 4096-sample segments at the plant's 10 kHz) of the
pooled episodes; their squares add up to the whole's but for the estimate's leakage. With --plot, the
first four episodes' error traces are drawn, one panel each, every controller in it.
"""
import argparse

import numpy as np
from scipy.signal import welch

from millvib_env.catalog.factory import load_controller
from millvib_env.tasks import get_task
from millvib_env.evaluation.evaluate import trace_episode

BANDS_HZ = ((0, 5), (5, 20), (20, 60), (60, 200), (200, 5000))


def tracking_error(name: str, task: str, seeds: list[int]) -> tuple[np.ndarray, float]:
    """e = xd - x (um) of controller `name` on `seeds`, every plant sample (rows: episodes), and the sample rate."""
    ctrl = load_controller(name, task, version="v1")
    runs = [trace_episode(ctrl, seed=s, task=task) for s in seeds]
    return np.stack([(r["xd"] - r["x"])[1:] for r in runs]) * 1e6, 1.0 / (runs[0]["t"][1] - runs[0]["t"][0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("controllers", nargs="+")
    ap.add_argument("--task", default="rolling")
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--plot", metavar="PNG", help="draw the first four episodes' error traces here")
    args = ap.parse_args()
    t = get_task(args.task)
    first = t.seeds["validation"].start
    seeds = list(range(first, first + args.episodes))
    print(f"{t.name}, validation plants {seeds[0]}-{seeds[-1]}: tracking error RMS (um), whole and per band")
    traces = {}
    for name in args.controllers:
        err, fs = tracking_error(name, t.name, seeds)
        traces[name] = err
        f, psd = welch(err, fs=fs, nperseg=4096, axis=1)
        psd, df = psd.mean(axis=0), f[1] - f[0]
        bands = [np.sqrt(psd[(f >= lo) & (f < hi)].sum() * df) for lo, hi in BANDS_HZ]
        print(f"{name:36s} {np.sqrt(np.mean(err ** 2)):6.2f} | "
              + "  ".join(f"{lo}-{hi} Hz {b:5.2f}" for (lo, hi), b in zip(BANDS_HZ, bands)), flush=True)
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from millvib_env._paths import save_figure

        n = min(4, len(seeds))
        fig, axes = plt.subplots(n, 1, figsize=(10, 2.2 * n), sharex=True, squeeze=False)
        for i, ax in enumerate(axes[:, 0]):
            for name, err in traces.items():
                ax.plot(np.arange(err.shape[1]) / fs, err[i], lw=0.7, label=name)
            ax.set_ylabel(f"plant {seeds[i]}\nxd - x (um)")
        axes[0, 0].legend(fontsize=7)
        axes[-1, 0].set_xlabel("t (s)")
        fig.tight_layout()
        print(f"wrote {save_figure(fig, args.plot, dpi=90)}")


if __name__ == "__main__":
    main()
