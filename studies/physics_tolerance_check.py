"""Diagnostic: can the girder PINN's physics tolerance be inferred from the data on a realistic crossing?

    python studies/physics_tolerance_check.py [--girder 0] [--crossing 0] [--profile fast]
        [--out reports/paper/diagnostics]

Crossing k of girder g of the realistic-crossing study (`studies/crossings.py`: the independent simulator,
a sprung truck on a rough road, 30 dB on the four gauges), analysed under today's model (the stated speed
and entry time, nothing declared). The modal reference, then the girder PINN with one segment (`uq.girder_pinn`,
one network, read on the crossing's clock, `methods.clock`), whose last layer is rebuilt with the PDE rows'
pseudo-sd at FACTORS times the fit's RMS PDE residual (the default is `girder_lastlayer.GIRDER_PDE_SD_FACTOR`). For each
factor: the log marginal likelihood of (log EI, log sigma) integrated on a grid (the evidence, up to a
constant shared by every factor), EI's posterior mean and sd, and z against the truth. If the evidence
picked a factor whose interval held the truth, the tolerance could be inferred. Minutes on one core.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import types
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies"))

import crossings as X  # noqa: E402

from bayespinn.methods.clock import on_entry_clock  # noqa: E402
from bayespinn.pipeline import analyse  # noqa: E402
from bayespinn.provenance import provenance  # noqa: E402
from bayespinn.uq import girder_pinn as G  # noqa: E402
from bayespinn.uq.girder_lastlayer import GIRDER_PDE_SD_FACTOR as PDE_SD_FACTOR  # noqa: E402

FACTORS = (1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1e3, 1e4, 1e5)
SNR_DB = 30.0
#: the grid in (log EI, log sigma): half-width in Laplace sds, and points per axis
HALF_WIDTH, POINTS = 7.0, (71, 41)


def rows(ll, phi_fit, log_ei_true: float) -> list[dict]:
    base = ll.s_f / PDE_SD_FACTOR
    out = []
    for fac in FACTORS:
        ll.s_f = base * fac
        z = ll.map(ll.start(phi_fit))
        sd = np.sqrt(np.diag(ll.covariance(z)))
        a = z[0] + np.linspace(-HALF_WIDTH, HALF_WIDTH, POINTS[0]) * sd[0]
        b = z[1] + np.linspace(-HALF_WIDTH, HALF_WIDTH, POINTS[1]) * sd[1]
        A, B = np.meshgrid(a, b, indexing="ij")
        lp = ll.log_post_many(np.c_[A.ravel(), B.ravel()]).reshape(A.shape)
        top = lp.max()
        w = np.exp(lp - top)
        evidence = top + math.log(w.sum() * (a[1] - a[0]) * (b[1] - b[0]))
        p = w.sum(1) / w.sum()
        mu = float(p @ a)
        s = float(math.sqrt(p @ (a - mu) ** 2))
        lo, hi = np.interp([0.05, 0.95], np.cumsum(p), a)
        row = {
            "factor": fac,
            "log_evidence": float(evidence),
            "EI_rel_error": math.exp(mu - log_ei_true) - 1,
            "sd_log_EI": s,
            "z": (mu - log_ei_true) / s,
            "hit": bool(lo <= log_ei_true <= hi),
            "grid_edge_mass": float(max(p[0], p[-1])),
        }
        print(row, flush=True)
        out.append(row)
    ll.s_f = base * PDE_SD_FACTOR
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--girder", type=int, default=0)
    ap.add_argument("--crossing", type=int, default=0)
    ap.add_argument("--profile", default="fast", choices=("smoke", "fast"))
    ap.add_argument("--out", type=Path, default=ROOT / "reports" / "paper" / "diagnostics")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    args = types.SimpleNamespace(family_seed=50, smoke=False)
    gcfg = X.girder_for(args, a.girder)
    d = X.draw(50, a.girder, a.crossing)
    data = X.simulate(X.truth_config(gcfg, d), SNR_DB, d["data_seed"], False)
    cfg = X.stated_config(gcfg, d, False, "constant")
    ei = gcfg.beam.EI
    t0 = time.perf_counter()
    ref = analyse(data, cfg, methods=["modal"], seed=1, truth={"EI": ei})
    m = ref.summary["methods"]["modal_mcmc"]
    reference = {
        "EI_rel_error": m["EI"]["mean"] / ei - 1,
        "z": (m["EI"]["mean"] - ei) / m["EI"]["sd"],
        "fit_check": m["fit_check"]["verdict"],
        "runtime_s": time.perf_counter() - t0,
    }
    print("reference", reference, flush=True)
    dc, cc, te = on_entry_clock(data, cfg)
    s = G.GirderNetSettings.for_profile(a.profile)
    pr = G.GirderProblem(dc, cc)
    fit = G.train_fit(pr, s, np.random.SeedSequence(1))
    ll = G.GirderLastLayer(pr, fit, s, np.random.SeedSequence(2))
    doc = {
        "crossing": f"g{a.girder}-c{a.crossing}",
        "truth_and_stated": d,
        "profile": a.profile,
        "entry_time_s": te,
        "reference": reference,
        "pinn_fit": {
            "EI_rel_error": math.exp(fit.phi[0]) / ei - 1,
            "network_share": ll.network_share,
        },
        "factors": rows(ll, fit.phi, math.log(ei)),
        "default_factor": PDE_SD_FACTOR,
        "provenance": {**provenance(), "command": " ".join(["python", *sys.argv]), "seed": 50},
    }
    a.out.mkdir(parents=True, exist_ok=True)
    path = a.out / f"physics-tolerance-g{a.girder}-c{a.crossing}.json"
    path.write_text(json.dumps(doc, indent=1, default=float) + "\n", encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
