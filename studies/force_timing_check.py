"""Where a crossing's speed and EI go wrong: the fluctuating-force posterior's peak on one crossing of the
crossings study, with the axles' fluctuations independent or sharing a part (the same road), on the
study's road or one without short wavelengths.

The crossing reference's EI error on the study's misses follows its speed error (EI x speed is what the
response's area fixes; the split comes from its timing). This finds the peak of the exact log posterior
(forces integrated out) from the study's start and from the truth, with Laplace sds, and the log posterior
with speed, entry time and EI held at the truth (the rest re-optimised): how strongly the data prefer the
wrong timing under each force law.

    python studies/force_timing_check.py --girder 1 --crossing 3 --law independent
    python studies/force_timing_check.py --girder 1 --crossing 3 --law shared --road-nmax 0.3
    python studies/force_timing_check.py --girder 1 --crossing 3 --law shared --band
    python studies/force_timing_check.py --girder 1 --crossing 3 --law shared --band --band-range 0.5,2.5

`--band` adds the force spectrum's band beyond the law's basis up to the road's reach
(`bayespinn.crossings.tail`), with every mode in that reach dynamic: the reference's law for a sprung
vehicle; without `--band` the law alone (the reference's law before the band). `--band-range` sets the
band in units of the first mode's frequency instead.
`--road-law` gives the axles' own and shared basis functions the band's prior sds too (the contact force
of a sprung body on an ISO 8608 road, `tail.relative_force_sd`, at the crossing's speed and suspension,
times s / `FORCE_S_MEDIAN`) in place of the inertial squared exponential, whose time scale l then enters
nothing; `--basis-to F` continues the axles' basis to F Hz (the reference's stops at 4 / `FORCE_L_MIN`
rad/s, 5.3 Hz).

    python studies/force_timing_check.py --girder 0 --crossing 3 --road-law --basis-to 21
    python studies/force_timing_check.py --girder 0 --crossing 3 --band

A diagnostic, not a study with records: it prints its table (one core, a few minutes).
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, str(Path(__file__).resolve().parent))
import crossings as S  # noqa: E402

from bayespinn.crossings import peak  # noqa: E402
from bayespinn.crossings.likelihood import CrossingsLogPosterior  # noqa: E402
from bayespinn.uq.priors import EIPrior, NoisePrior  # noqa: E402


def crossing_data(g: int, k: int, road_nmax: float | None):
    import bayespinn.vbi.crossings as vc
    from bayespinn.vbi.road import iso8608_road

    args = S.build_parser().parse_args([])
    gcfg = S.girder_for(args, g)
    d = S.draw(args.seed, g, k)
    if road_nmax is not None:  # the study's road without wavelengths under 1 / road_nmax
        vc.iso8608_road = functools.partial(iso8608_road, n_max=road_nmax)
    data = S.simulate(S.truth_config(gcfg, d), args.snr, d["data_seed"], False)
    return gcfg, d, data


def posterior(
    gcfg, d, data, law: str, band: bool = False
) -> tuple[CrossingsLogPosterior, np.ndarray]:
    cfg = S.stated_config(gcfg, d, True, "fluctuating", "sprung")
    damping = (cfg.prior.damping_median, cfg.prior.damping_log_sd)

    def post_of(n):
        terms = peak.terms(cfg, data, n, True, band=band)
        for c in terms:
            c.common = law == "shared"
        return CrossingsLogPosterior(
            terms, EIPrior.from_spec(cfg.prior),
            NoisePrior.build("vague", np.asarray(data.value, float)),
            zeta_known=cfg.beam.damping_ratio, damping_prior=damping, forces=True,
            mode_damping_prior=damping,
        )  # fmt: skip

    post = post_of(8)
    th, sigma = peak.least_squares_fit(post, peak.start(post, cfg))
    n, _ = peak.choose_modes(cfg, data, post_of, th, sigma)
    if n != 8:
        post = post_of(n)
        th, sigma = peak.least_squares_fit(post, th)
    th = peak.fluctuation_start(post, th, sigma)
    return post, th


def use_road_law() -> None:
    """The axles' basis functions' prior sds from the road and the suspension (`--road-law`)."""
    from bayespinn.crossings import likelihood as lk
    from bayespinn.crossings.forward import basis_frequencies
    from bayespinn.crossings.tail import relative_force_sd

    inertial = lk.CrossingTerm.column_sds

    def column_sds(self, p, i):
        rest = inertial(self, p, i)
        alpha, _, _ = basis_frequencies(self.model.L / p["v"][i], self.model.n_basis)
        level = np.asarray(p["s"], float)[:, None] / lk.FORCE_S_MEDIAN
        f = relative_force_sd(alpha, p["v"][i], p["fb"][i], p["zb"][i]) * level
        d = np.tile(f, (1, self.model.loads.size))
        if self.common:
            r = np.asarray(p["r"], float)[:, None]
            d = np.concatenate([d * np.sqrt(1.0 - r), f * np.sqrt(r)], axis=1)
        return np.concatenate([d, rest[:, d.shape[1] :]], axis=1)

    lk.CrossingTerm.column_sds = column_sds


def basis_to(hz: float) -> None:
    """The axles' basis continued to hz (`--basis-to`): `n_basis_for` as if the law's shortest time scale
    were 4 / (2 pi hz)."""
    from bayespinn.crossings import likelihood as lk

    ell = lk.BASIS_CUTOFF / (2 * math.pi * hz)
    peak.n_basis_for = functools.partial(lk.n_basis_for, l_min=ell, cap=10**6)


def tail_range() -> tuple[float, float] | None:
    from bayespinn.crossings import tail

    return tail.BAND


def maximise(f, th, free=None):
    free = np.arange(th.size) if free is None else np.asarray(free)
    z = th.copy()

    def g(zf):
        zz = z.copy()
        zz[free] = zf
        return f(zz)

    for _ in range(3):
        res = minimize(g, z[free], method="Powell", options={"maxiter": 20000, "xtol": 1e-6})
        z[free] = res.x
    return z, -res.fun


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--girder", type=int, default=1)
    p.add_argument("--crossing", type=int, default=3)
    p.add_argument("--law", choices=("independent", "shared"), default="shared")
    p.add_argument("--road-nmax", type=float, default=None, help="cycles/m; default the ISO band's")
    p.add_argument(
        "--band", action="store_true", help="the force spectrum's band up to the road's reach"
    )
    p.add_argument(
        "--band-range", default=None, help="lo,hi in first-mode frequencies, e.g. 0.5,1.6"
    )
    p.add_argument("--road-law", action="store_true", help="the road's law on the axles' basis")
    p.add_argument("--basis-to", type=float, default=None, help="Hz the axles' basis reaches")
    a = p.parse_args(argv)
    if a.road_law:
        use_road_law()
    if a.basis_to is not None:
        basis_to(a.basis_to)
    if a.band_range is not None:
        from bayespinn.crossings import tail

        lo, hi = (float(v) for v in a.band_range.split(","))
        tail.BAND = (lo, hi)
    gcfg, d, data = crossing_data(a.girder, a.crossing, a.road_nmax)
    post, th = posterior(gcfg, d, data, a.law, a.band)
    names = post.layout.names

    def f(z):
        return -float(post(z[None])[0])

    truth = {"log_EI": math.log(gcfg.beam.EI), "log_zeta": math.log(d["damping_ratio"])}
    for n in names:
        for key, val in (("log_v", math.log(d["speed"])), ("t0", d["entry_time"]),
                         ("log_fb", math.log(d["body_frequency"])),
                         ("log_zb", math.log(d["body_damping"]))):  # fmt: skip
            if n.startswith(key + "["):
                truth[n] = val
    peak1, lp1 = maximise(f, th)
    held = [i for i, n in enumerate(names) if n == "log_EI" or n.startswith(("log_v[", "t0["))]
    at = peak1.copy()
    for i in held:
        at[i] = truth[names[i]]
    at, lp_truth = maximise(f, at, [i for i in range(at.size) if i not in held])
    peak2, lp2 = maximise(f, at)
    best, lp = (peak1, lp1) if lp1 >= lp2 else (peak2, lp2)
    h = np.array([peak.step(n, post) for n in names])
    sd = peak.hessian_scale(post, best, h)
    band = f", band {tail_range() or 'to the road reach'}" if a.band else ""
    band += ", road law" if a.road_law else ""
    band += (
        f", basis to {a.basis_to:g} Hz ({post.terms[0].model.n_basis} per axle)"
        if a.basis_to
        else ""
    )
    print(f"girder {a.girder} crossing {a.crossing}, {a.law} axles, road n_max {a.road_nmax}{band}")
    print(
        f"log posterior at the peak {lp:.2f}; with speed, entry time and EI at the truth {lp_truth:.2f}"
    )
    for i, n in enumerate(names):
        z = (best[i] - truth[n]) / sd[i] if n in truth else float("nan")
        print(f"  {n:20s} {best[i]:12.6f}  sd {sd[i]:.2e}  z {z:+.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
