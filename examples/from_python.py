"""bayespinn from Python: simulate a dataset, analyse it in memory, print the intervals, write the run.

    python examples/from_python.py --snr 20 --methods modal,ensemble,bpinn --out reports/runs/example

The same as `bayespinn run`, step by step: `resolve` the bridge, `simulate` (or `read_csv`) the data,
`analyse` them in memory, and `write_run` the report folder only if --out is given.
"""

from __future__ import annotations

import argparse

import bayespinn as bp


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--case", default="deflection", help="deflection or strain")
    p.add_argument("--config", default=None, help="a TOML file over the Exeter preset")
    p.add_argument("--snr", type=float, default=20.0, help="SNR of the synthetic data [dB]")
    p.add_argument("--methods", default="modal", help="comma list of modal, ensemble, bpinn")
    p.add_argument("--profile", default="fast", help="smoke, fast or paper")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="write the run folder here (default: write nothing)")
    args = p.parse_args(argv)

    cfg = bp.resolve(args.case, toml=args.config)
    data = bp.simulate(cfg, snr_db=args.snr, seed=args.seed)
    result = bp.analyse(
        data,
        cfg,
        methods=args.methods,
        seed=args.seed,
        profile=args.profile,
        truth={"EI": cfg.beam.EI},
        snr_db=args.snr,
    )
    for key, post in result.posteriors.items():
        lo, hi = post.interval(0.9)
        print(f"{key:>10}: EI {post.EI.mean():.5g} N m^2, 90 % interval [{lo:.5g}, {hi:.5g}]")
    if args.out:
        print("wrote", bp.write_run(result, args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
