"""Diagnostic (issue 21, strain): how the ensemble members' EI marginals move with the PDE pseudo-sd.

    python studies/pde_sd_sweep.py BRIDGE [--case strain] [--profile fast] [--out reports/paper/diagnostics]

Bridge BRIDGE of family seed 0 at 30 dB (the family study's data seed): the modal reference, then the
deep ensemble (fast profile, 5 members, trained in this process one member at a time). The members'
phase-2 networks are kept, and each one's last-layer model is rebuilt with `lastlayer.PDE_SD_FACTOR` set
to 1, 3, 10 (the default), 30 and 100: the features stay fixed, only the PDE rows' pseudo-sd changes.
For each factor it writes every member's marginal mean as z = (mean - reference mean) / reference sd (log
EI), its width over the reference's, and the equal mixture's z and width
(`ensemble.pool_log_ei`, the ensemble's own pooling). Minutes per bridge on one core.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bayespinn.uq.ensemble as E  # noqa: E402
import bayespinn.uq.lastlayer as LL  # noqa: E402
from bayespinn import family, methods  # noqa: E402
from bayespinn.data.synthetic import simulate  # noqa: E402
from bayespinn.executor import Executor  # noqa: E402
from bayespinn.options import RunOptions  # noqa: E402
from bayespinn.pipeline import analyse  # noqa: E402
from bayespinn.uq.priors import NoisePrior  # noqa: E402
from bayespinn.uq.shared_fit import ensemble_seed  # noqa: E402

FACTORS = (1.0, 3.0, 10.0, 30.0, 100.0)
SNR_DB = 30.0


def sweep(index: int, case: str, profile: str = "fast") -> dict:
    b = family.bridge(index, 0, case)
    seq = family.data_seed(0, index)
    data = simulate(b.cfg, SNR_DB, seq)
    res = analyse(
        data, b.cfg, methods=["modal"], seed=seq, snr_db=SNR_DB, opts=RunOptions(profile=profile)
    )
    lr = np.log(res.posteriors[methods.reference_key()].EI.ravel())
    rmu, rsd = float(lr.mean()), float(lr.std())
    # keep each member's last-layer inputs and the pooling's inputs as the ensemble builds them
    calls, cap = [], {}
    orig_ll, orig_pool = E._last_layer, E.pooled_posterior

    def rec_ll(*a, **k):
        calls.append((a, k))
        return orig_ll(*a, **k)

    def rec_pool(p1, p2, sigma_hat, base, ei_prior, *a, **k):
        cap.update(p2=p2, base=base, prior=ei_prior)
        return orig_pool(p1, p2, sigma_hat, base, ei_prior, *a, **k)

    noise = NoisePrior.build("vague", data.value, SNR_DB)
    E._last_layer, E.pooled_posterior = rec_ll, rec_pool
    try:
        post = E.ensemble_posterior(
            data,
            b.cfg,
            seed=ensemble_seed(seq),
            members=5,
            profile=profile,
            device="cpu",
            noise=noise,
            executor=Executor("local", workers=1),
        )
    finally:
        E._last_layer, E.pooled_posterior = orig_ll, orig_pool
    le = np.log(post.EI.ravel())
    out = {
        "bridge": index,
        "case": case,
        "profile": profile,
        "alpha": family.speed_parameter(b.cfg),
        "ref_mean_log_EI": rmu,
        "ref_sd_log_EI": rsd,
        "ensemble_z": float((le.mean() - rmu) / rsd),
        "ensemble_sd_ratio": float(le.std() / rsd),
        "factors": {},
    }
    p2, base, prior = cap["p2"], cap["base"], cap["prior"]
    shifts = [math.log(base.EI_ref) - math.log(f) for f in p2.beta_factor]
    default = LL.PDE_SD_FACTOR
    try:
        for fac in FACTORS:
            LL.PDE_SD_FACTOR = fac
            marginals = []
            for (a, k), sh in zip(calls[-len(shifts) :], shifts, strict=True):  # phase 2's members
                ll = orig_ll(*a, **k)
                g = E.sigma_grid(ll, noise)
                marginals.append(
                    E.member_marginal(ll, g, prior, sh, float(E.local_sd(ll, g, prior)))
                )
            mm_ok = [m for m in marginals if m is not None]
            mu, _, _, _, var = E.pool_log_ei(np.log(p2.EI), marginals, prior.log_sd)
            out["factors"][f"{fac:g}"] = {
                "member_z": [round((m.mean - rmu) / rsd, 3) for m in mm_ok],
                "member_width": [round(math.sqrt(m.var) / rsd, 3) for m in mm_ok],
                "mixture_z": (mu - rmu) / rsd,
                "mixture_sd_ratio": math.sqrt(var) / rsd,
            }
            print(index, fac, out["factors"][f"{fac:g}"], flush=True)
    finally:
        LL.PDE_SD_FACTOR = default
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bridge", type=int)
    ap.add_argument("--case", default="strain", choices=("strain", "deflection"))
    ap.add_argument("--profile", default="fast", choices=("smoke", "fast", "paper"))
    ap.add_argument("--out", type=Path, default=ROOT / "reports" / "paper" / "diagnostics")
    a = ap.parse_args(argv)
    out = sweep(a.bridge, a.case, a.profile)
    a.out.mkdir(parents=True, exist_ok=True)
    path = a.out / f"pde-sd-{a.case}-bridge{a.bridge}.json"
    path.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
