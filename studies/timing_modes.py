"""Whether a crossing's timing has more than one mode: the exact log posterior profiled over the speed, and
the declared analysis re-run with the stated speed and entry time moved onto the truth.

The crossings study's misses come with the speed and the entry time inferred several sds off
(`reports/paper/crossings.md`). This asks, on one of its crossings (same seeds, same data), whether the
analysis found the posterior's only peak or one of several:

- profile: at each speed on a grid (+-1.2 % of the truth), the entry time and log EI maximised under the
  exact log posterior (forces integrated out), from several entry times about the ridge that keeps the
  lorry at midspan on time; the other parameters stay at the peak the reference starts from. Several
  ridges show as branches of the entry time.
- `--at-truth`: the declared analysis (`studies/crossings.py`'s) with the stated speed and entry time set to
  their truths, their sds unchanged: where the sampler lands when it starts from the truth.

    python studies/timing_modes.py --girder 2 --crossing 5
    python studies/timing_modes.py --girder 2 --crossing 5 --at-truth

A diagnostic, not a study with records: it prints its table (one core; the profile about 2 minutes, the
analysis as long as the study's).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, str(Path(__file__).resolve().parent))
import crossings as S  # noqa: E402
import force_timing_check as F  # noqa: E402

from bayespinn.crossings.linearised import exact_log_posterior  # noqa: E402

#: the speed grid, relative to the truth, and the entry-time starts about the midspan ridge [s]
SPEEDS = np.linspace(-0.012, 0.012, 25)
T0_STARTS = (-0.02, 0.0, 0.02)


def profile(g: int, k: int) -> list[dict]:
    gcfg, d, data = F.crossing_data(g, k, None)
    post, th = F.posterior(gcfg, d, data, "shared")
    name = post.terms[0].name
    iv, it = post.layout.index[f"log_v[{name}]"], post.layout.index[f"t0[{name}]"]
    mid = gcfg.beam.length / 2
    rows = []
    for rel in SPEEDS:
        z = th.copy()
        z[iv] = math.log(d["speed"] * (1 + rel))
        ridge = th[it] + mid / math.exp(th[iv]) - mid / math.exp(z[iv])
        best = None
        for dt in T0_STARTS:

            def f(u, z=z):
                zz = z.copy()
                zz[[it, 0]] = u
                return -float(exact_log_posterior(post, zz[None])[0])

            r = minimize(f, [ridge + dt, th[0]], method="Nelder-Mead",
                         options={"xatol": 1e-6, "fatol": 0.05, "maxiter": 300})  # fmt: skip
            if best is None or r.fun < best.fun:
                best = r
        rows.append({
            "speed_rel": float(rel), "log_post": float(-best.fun),
            "entry_error_s": float(best.x[0] - d["entry_time"]),
            "EI_rel": float(math.exp(best.x[1]) / gcfg.beam.EI - 1),
        })  # fmt: skip
    return rows


def at_truth(g: int, k: int) -> dict:
    args = S.build_parser().parse_args([])
    gcfg = S.girder_for(args, g)
    d = S.draw(args.seed, g, k)
    data = S.simulate(S.truth_config(gcfg, d), args.snr, d["data_seed"], False)
    moved = {**d, "stated_speed": d["speed"], "stated_entry_time": d["entry_time"]}
    cfg = S.stated_config(gcfg, moved, True, args.forces, args.vehicle)
    e = S.analyse(data, cfg, gcfg.beam.EI, args.snr, d["data_seed"] % 1000, False)
    rec = {"truth_and_stated": d, "declared": e}
    return {
        "EI_z": e["z"],
        "hit": e["hit"],
        "speed_z": S.nuisance_z(rec, "speed"),
        "entry_z": S.nuisance_z(rec, "entry_time"),
        "runtime_s": e["runtime_s"],
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--girder", type=int, default=2)
    p.add_argument("--crossing", type=int, default=5)
    p.add_argument(
        "--at-truth", action="store_true", help="re-run the analysis started at the truth"
    )
    a = p.parse_args(argv)
    if a.at_truth:
        r = at_truth(a.girder, a.crossing)
        print(
            f"g{a.girder}-c{a.crossing}, stated at the truth: EI z {r['EI_z']:+.2f} (hit {r['hit']}), "
            f"speed z {r['speed_z']:+.1f}, entry z {r['entry_z']:+.1f}, {r['runtime_s']:.0f} s"
        )
        return 0
    print("| speed - truth | log posterior | entry time - truth [s] | EI - truth |")
    print("|---|---|---|---|")
    for r in profile(a.girder, a.crossing):
        print(
            f"| {100 * r['speed_rel']:+.1f} % | {r['log_post']:.1f} | {r['entry_error_s']:+.4f} | "
            f"{100 * r['EI_rel']:+.3f} % |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
