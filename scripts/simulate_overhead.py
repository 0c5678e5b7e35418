"""simulate()'s cost against its compiled kernel's on the paper's nine cases (1 s each), 20 rounds:
the share of a call that is not integration (argument checks, packing, the result object).

    python scripts/simulate_overhead.py
"""
import cProfile
import pstats

from millvib_env.analysis.studies import PAPER_STUDIES
from millvib_env.plant.integrate import simulate


def main() -> None:
    cases = [(c.params, c.gains) for s in PAPER_STUDIES for c in s.cases]
    for p, g in cases:  # compile / load the kernels first
        simulate(p, g, 1.0)
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(20):
        for p, g in cases:
            simulate(p, g, 1.0)
    prof.disable()
    stats = pstats.Stats(prof).stats
    total = sum(v[3] for k, v in stats.items() if k[2] == "simulate")
    kernel = sum(v[3] for k, v in stats.items() if k[2] == "simulate_batch_serial")
    n = 20 * len(cases)
    print(f"simulate() {total / n * 1e3:.3f} ms per call, its kernel {kernel / n * 1e3:.3f} ms: "
          f"{total / kernel:.2f}x (under cProfile; the auxiliary outputs a, u, xv, QL, Ff, ps are computed on "
          "first access, not here)")


if __name__ == "__main__":
    main()
