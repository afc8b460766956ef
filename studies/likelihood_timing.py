"""The cost of one exact crossing likelihood (forces integrated out, the sprung vehicle's interaction
integrated in time) on one crossing of the crossings study, at the study's starting point, evaluated one
set at a time and in batches.

The crossing reference's importance sampler and its checks spend their time here; compare commits by
running this script on each, on the same machine in the same session (the machines are shared and noisy).

    python studies/likelihood_timing.py --girder 0 --crossing 0

A benchmark, not a study with records: it prints its table (one core, about a minute).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from force_timing_check import crossing_data, posterior  # noqa: E402

BATCHES = (1, 2, 4, 8, 16, 32)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--girder", type=int, default=0)
    p.add_argument("--crossing", type=int, default=0)
    p.add_argument("--sets", type=int, default=64, help="parameter sets timed per batch size")
    args = p.parse_args(argv)
    gcfg, d, data = crossing_data(args.girder, args.crossing, None)
    post, th = posterior(gcfg, d, data, "shared")
    rng = np.random.default_rng(0)
    sets = th[None] + 1e-4 * rng.standard_normal((args.sets, th.size))
    post(sets[:2])  # warm caches and lazily built tables
    print(f"g{args.girder}-c{args.crossing}: {len(data)} samples, {th.size} parameters")
    print("| batch | ms per parameter set |")
    print("|---|---|")
    for b in BATCHES:
        t = time.perf_counter()
        for lo in range(0, args.sets, b):
            post(sets[lo : lo + b])
        print(f"| {b} | {1e3 * (time.perf_counter() - t) / args.sets:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
