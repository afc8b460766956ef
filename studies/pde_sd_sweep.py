"""Diagnostic (strain case): how the ensemble members' EI marginals move with the PDE pseudo-sd.

    python studies/pde_sd_sweep.py BRIDGE [--case strain] [--family-seed 0] [--profile fast]
        [--out reports/paper/diagnostics]

Bridge BRIDGE of family seed 0 (or `--family-seed`; never the held-out family, which chooses nothing) at
30 dB (the family study's data seed): the modal reference, then the deep ensemble (fast profile, 5
members, trained in this process one member at a time). The members' phase-2 networks are kept, and each
one's last-layer model is rebuilt with `lastlayer.PDE_SD_FACTOR` set to 1 (the default), 3, 10 (the
earlier default), 30 and 100: the features stay fixed, only the PDE rows' pseudo-sd changes. For each
factor it writes every member's marginal mean as z = (mean - reference mean) / reference sd (log EI), its
width over the reference's, and the equal mixture's z and width (`ensemble.pool_log_ei`, the ensemble's
own pooling). Minutes per bridge on one core.

Two rows derive the PDE rows' weight from each member's own residual field r(xi, tau) instead of a factor:
a stationary correlation model (a Matern-5/2 correlation in xi times one in tau, plus an uncorrelated
share, fitted to r by maximum likelihood on `CORR_FIT_POINTS` of its points) gives

- "ess": the effective number of independent residuals n_eff = n^2 / sum_ij C_ij (the count whose mean
  is as uncertain as the n correlated ones'), and the independent-rows model with the pseudo-sd the RMS
  residual times sqrt(n / n_eff): the factor that the module docstring's argument asks for;
- "gls": the PDE rows whitened by the fitted correlation (generalised least squares; the pseudo-sd the
  whitened residual's RMS): the correlated-discrepancy model itself.

``--cache DIR`` keeps each bridge's trained members (`torch.save`), so a later run re-analyses them without
training.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bayespinn.uq.ensemble as E  # noqa: E402
import bayespinn.uq.lastlayer as LL  # noqa: E402
from bayespinn import family, methods  # noqa: E402
from bayespinn.data.synthetic import simulate  # noqa: E402
from bayespinn.executor import Executor  # noqa: E402
from bayespinn.options import RunOptions  # noqa: E402
from bayespinn.pipeline import analyse  # noqa: E402
from bayespinn.provenance import provenance  # noqa: E402
from bayespinn.uq.priors import NoisePrior  # noqa: E402
from bayespinn.uq.shared_fit import ensemble_seed  # noqa: E402

FACTORS = (1.0, 3.0, 10.0, 30.0, 100.0)
SNR_DB = 30.0
#: residual points the correlation model is fitted on (a random subset; the Cholesky costs n^3 / 3)
CORR_FIT_POINTS = 600
#: starting lengthscales of the fit (unit square); the best of the starts is kept
CORR_STARTS = ((0.03, 0.03), (0.1, 0.1), (0.3, 0.3), (0.3, 0.03), (0.03, 0.3))


def _matern52(d: np.ndarray, ell: float) -> np.ndarray:
    a = math.sqrt(5.0) * np.abs(d) / ell
    return (1.0 + a + a * a / 3.0) * np.exp(-a)


def correlation(xi, tau, ell_xi: float, ell_tau: float, nugget: float, at=None) -> np.ndarray:
    """Correlation of the residual between the points (xi, tau) of the unit square and the points ``at``
    (xi2, tau2; default the same points): Matern-5/2 in each coordinate, a share nugget / (1 + nugget)
    uncorrelated (on the diagonal, for the same points)."""
    x2, t2 = (xi, tau) if at is None else at
    k = _matern52(xi[:, None] - x2[None, :], ell_xi) * _matern52(
        tau[:, None] - t2[None, :], ell_tau
    )
    if at is None:
        k = k + nugget * np.eye(len(xi))
    return k / (1.0 + nugget)


def fit_correlation(xi, tau, r, rng: np.random.Generator) -> dict:
    """Maximum-likelihood correlation model of the residual field r (zero mean, its variance profiled out)
    on `CORR_FIT_POINTS` random points of it; with the effective count n_eff over all its points."""
    from scipy.optimize import minimize

    n = len(r)
    idx = rng.choice(n, min(CORR_FIT_POINTS, n), replace=False)
    x, t, y = xi[idx], tau[idx], r[idx] / math.sqrt(float(np.mean(r[idx] ** 2)))
    m = len(y)

    def nll(p):
        lx, lt, nug = np.exp(p)
        try:
            L = np.linalg.cholesky(correlation(x, t, lx, lt, nug) + 1e-10 * np.eye(m))
        except np.linalg.LinAlgError:
            return 1e10
        a = np.linalg.solve(L, y)
        return 0.5 * m * math.log(float(a @ a) / m) + float(np.log(np.diag(L)).sum())

    bounds = [(math.log(1e-3), math.log(10.0))] * 2 + [(math.log(1e-6), math.log(1e3))]
    best = min(
        (
            minimize(nll, np.log([*l0, 0.01]), method="L-BFGS-B", bounds=bounds)
            for l0 in CORR_STARTS
        ),
        key=lambda res: res.fun,
    )
    lx, lt, nug = (float(v) for v in np.exp(best.x))
    total = sum(  # the Matern part over every pair of points, in blocks of rows
        float(correlation(xi[i : i + 500], tau[i : i + 500], lx, lt, nug, at=(xi, tau)).sum())
        for i in range(0, n, 500)
    )
    total += nug * n / (1.0 + nug)  # the uncorrelated share, on the diagonal
    n_eff = n * n / total
    return {
        "n": n,
        "ell_xi": lx,
        "ell_tau": lt,
        "nugget": nug,
        "n_eff": n_eff,
        "factor": math.sqrt(n / n_eff),
    }


def residual(ll: LL.LastLayer) -> tuple[torch.Tensor, ...]:
    """The member's design rows and its PDE residual at the fit, r = theta P4 beta + P2 beta - f."""
    rows = ll.rows(lambda xi, tau, kx, kt: LL.feature_jet(ll.model, 0, xi, tau, kx, kt))
    _, P4, P2, _, _ = rows
    return rows, ll.theta_fit * P4 @ ll.beta_fit + P2 @ ll.beta_fit - ll.f


def gls_view(ll: LL.LastLayer, rows: tuple, fit: dict) -> LL.LastLayer:
    """The member's last-layer model with its PDE rows (and load) whitened by the fitted correlation;
    ``rows`` its design rows (`residual`)."""
    if ll.pde_v is not None:
        raise ValueError("the GLS view needs free vibrations that solve the PDE exactly")
    D, P4, P2, Bm, Cm = rows
    xi, tau = ll.xi_f.numpy(), ll.tau_f.numpy()
    C = correlation(xi, tau, fit["ell_xi"], fit["ell_tau"], fit["nugget"]) + 1e-10 * np.eye(len(xi))
    L = torch.as_tensor(np.linalg.cholesky(C))
    w = lambda X: torch.linalg.solve_triangular(L, X, upper=False)  # noqa: E731
    view = copy.copy(ll)
    P4w, P2w, fw = w(P4), w(P2), w(ll.f[:, None])[:, 0]
    view.f = fw
    view.s_f = max(
        float((ll.theta_fit * P4w @ ll.beta_fit + P2w @ ll.beta_fit - fw).pow(2).mean().sqrt()),
        LL.MIN_PSEUDO_SD,
    )
    view._gram(D, P4w, P2w, Bm, Cm)
    return view


def train(index: int, case: str, profile: str = "fast", family_seed: int = 0) -> dict:
    """The reference and one deep ensemble on the bridge; returns what the rebuilds need (`torch.save`-able):
    the phase-2 members' last-layer inputs, their log EI shifts and trained log EIs, the priors, and the
    reference's and the ensemble's own summaries."""
    b = family.bridge(index, family_seed, case)
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
    p2, base = cap["p2"], cap["base"]
    shifts = [math.log(base.EI_ref) - math.log(f) for f in p2.beta_factor]
    return {
        "summary": {
            "bridge": index,
            "family_seed": family_seed,
            "case": case,
            "profile": profile,
            "alpha": family.speed_parameter(b.cfg),
            "ref_mean_log_EI": rmu,
            "ref_sd_log_EI": rsd,
            "ensemble_z": float((le.mean() - rmu) / rsd),
            "ensemble_sd_ratio": float(le.std() / rsd),
        },
        "calls": calls[-len(shifts) :],  # phase 2's members
        "shifts": shifts,
        "log_ei": np.log(p2.EI),
        "prior": cap["prior"],
        "noise": noise,
    }


def rebuild(state: dict) -> dict:
    """Every member's last-layer marginal at each factor, at its own residual's "ess" factor, and in the
    "gls" model; with the equal mixture of each row."""
    out = dict(state["summary"], factors={}, residual_correlation=[])
    rmu, rsd = out["ref_mean_log_EI"], out["ref_sd_log_EI"]
    prior, noise, shifts = state["prior"], state["noise"], state["shifts"]

    def row(lls):
        marginals = []
        for ll, sh in zip(lls, shifts, strict=True):
            g = E.sigma_grid(ll, noise)
            marginals.append(E.member_marginal(ll, g, prior, sh, float(E.local_sd(ll, g, prior))))
        mm_ok = [m for m in marginals if m is not None]
        mu, _, _, _, var = E.pool_log_ei(state["log_ei"], marginals, prior.log_sd)
        return {
            "member_z": [round((m.mean - rmu) / rsd, 3) for m in mm_ok],
            "member_width": [round(math.sqrt(m.var) / rsd, 3) for m in mm_ok],
            "mixture_z": (mu - rmu) / rsd,
            "mixture_sd_ratio": math.sqrt(var) / rsd,
        }

    default = LL.PDE_SD_FACTOR
    try:
        build = lambda: [E._last_layer(*a, **k) for a, k in state["calls"]]  # noqa: E731
        for fac in FACTORS:
            LL.PDE_SD_FACTOR = fac
            out["factors"][f"{fac:g}"] = row(build())
            print(out["bridge"], fac, out["factors"][f"{fac:g}"], flush=True)
        LL.PDE_SD_FACTOR = 1.0
        lls = build()
        fits, rows = [], []
        for m, ll in enumerate(lls):
            rw, r = residual(ll)
            rows.append(rw)
            rng = np.random.default_rng(m)
            fits.append(fit_correlation(ll.xi_f.numpy(), ll.tau_f.numpy(), r.numpy(), rng))
        out["residual_correlation"] = [{k: round(v, 4) for k, v in f.items()} for f in fits]
        ess = []
        for (a, k), f in zip(state["calls"], fits, strict=True):
            LL.PDE_SD_FACTOR = f["factor"]
            ess.append(E._last_layer(*a, **k))
        out["factors"]["ess"] = row(ess)
        print(out["bridge"], "ess", out["factors"]["ess"], flush=True)
        out["factors"]["gls"] = row(
            [gls_view(ll, rw, f) for ll, rw, f in zip(lls, rows, fits, strict=True)]
        )
        print(out["bridge"], "gls", out["factors"]["gls"], flush=True)
    finally:
        LL.PDE_SD_FACTOR = default
    return out


def stem(case: str, index: int, family_seed: int = 0) -> str:
    """The bridge's file stem: family seed 0's keep their first names."""
    fam = f"family{family_seed}-" if family_seed else ""
    return f"{case}-{fam}bridge{index}"


def sweep(
    index: int, case: str, profile: str = "fast", cache: Path | None = None, family_seed: int = 0
) -> dict:
    """`train` (or its cached result) then `rebuild`."""
    name = stem(case, index, family_seed)
    path = None if cache is None else cache / f"members-{name}-{profile}.pt"
    if path is not None and path.exists():
        state = torch.load(path, weights_only=False)
    else:
        state = train(index, case, profile, family_seed)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            torch.save(state, path)
    return rebuild(state)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bridge", type=int)
    ap.add_argument("--case", default="strain", choices=("strain", "deflection"))
    ap.add_argument("--profile", default="fast", choices=("smoke", "fast", "paper"))
    ap.add_argument("--out", type=Path, default=ROOT / "reports" / "paper" / "diagnostics")
    ap.add_argument("--cache", type=Path, default=None, help="folder keeping the trained members")
    ap.add_argument(
        "--family-seed", type=int, default=0, help="the family (default 0, the development family)"
    )
    a = ap.parse_args(argv)
    if a.family_seed == family.HELD_OUT_SEED:
        ap.error(f"--family-seed {a.family_seed} is the held-out family, which chooses nothing")
    out = sweep(a.bridge, a.case, a.profile, a.cache, a.family_seed)
    out["provenance"] = {
        **provenance(),
        "command": " ".join(["python", "studies/pde_sd_sweep.py", *(argv or sys.argv[1:])]),
        "seed": 0,  # the family study's root seed: bridge B's data and analysis use family.data_seed(0, B)
    }
    a.out.mkdir(parents=True, exist_ok=True)
    path = a.out / f"pde-sd-{stem(a.case, a.bridge, a.family_seed)}.json"
    path.write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
