"""What an episode's severity costs: the environments' two transforms of 200 records, timed in one warm process.

    python scripts/severity_time.py [--rows 200] [--workers 1] [--calls 5]

`band_levels_rows` over whole episodes (10,001 samples at 10 kHz: broadband, pump line and 10-100 Hz) and
`vibration_severity_rows` over their rest after 0.1 s (9,001 samples), milliseconds per call (a warm-up call
first), on random walks seeded with 1. The numbers are this machine's, under whatever else it is doing: a
benchmark, never a test.
"""
import argparse
import timeit

import numpy as np

from millvib_env.severity import band_levels_rows, vibration_severity_rows


def per_call_ms(fn, calls: int) -> float:
    fn()  # the warm-up call
    return timeit.timeit(fn, number=calls) / calls * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=int, default=200)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--calls", type=int, default=5)
    args = parser.parse_args()
    fs = 10_000.0
    records = np.cumsum(np.random.default_rng(1).normal(size=(args.rows, 10_001)), axis=1) * 1e-3
    whole = per_call_ms(lambda: band_levels_rows(records, fs, workers=args.workers), args.calls)
    rest = per_call_ms(lambda: vibration_severity_rows(records[:, 1000:], fs, workers=args.workers), args.calls)
    print(f"band_levels_rows, {args.rows} x 10001: {whole:.1f} ms; vibration_severity_rows, {args.rows} x 9001: "
          f"{rest:.1f} ms ({args.workers} scipy thread(s))")


if __name__ == "__main__":
    main()
