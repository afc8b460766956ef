"""Diagnostic: does a resonant first-mode term explain what today's fluctuating-force law misses?

On a crossing of the crossings study (`studies/crossings.py`, same seeds), with every parameter of the
analysis model at its truth (EI, damping, speed, entry time, suspension), the force law's hyperparameters
(scale, time scale, noise sd) are fitted by maximum marginal likelihood, the forces integrated out exactly,
under these laws (`--laws`, default the first two):

- `today`: the reference's law (each axle's dynamic force a Gaussian process with the inertial spectrum,
  time scale at least 0.12 s, its basis below 5.3 Hz);
- `resonant`: today's law plus the first mode's response to a broadband force, a Gaussian process in
  time for the girder's first modal coordinate with the spectrum of a damped oscillator at that mode
  (frequency from EI, damping ratio the girder's), on the span's time window from the first axle's entry
  to 1 s after the last one leaves (basis 0.3-2 times the first frequency); its scale is fitted.
- `coupled`: as `resonant`, but the oscillator is the first mode of the girder coupled to the lorry's
  sprung bodies (`bayespinn.crossings.resonance.coupled_mode`, the lorry centred on the span, at the crossing's EI, girder damping and
  suspension): a heavy lorry's dampers raise the mode's frequency and damping well above the bare girder's.
- `free`: as `resonant`, the oscillator's frequency and damping ratio fitted too (an upper bound on what
  the resonant term's spectrum can explain).
- `two-mode`: `coupled` plus the second mode's coordinate as a second resonant term (the bare girder's
  second frequency, 4 times the first; basis 0.5-1.5 times it; its scale and damping ratio fitted): on the
  family girders that mode (18-22 Hz) is within the forces' reach.

Per law: the log marginal likelihood at its maximum, the fitted response's RMS error against the
noise-free truth in noise sds, and the log EI profile (hyperparameters re-fitted at each of 9 points
within +-0.8 %; its quadratic fit's peak and sd). This check chose the law the reference now
carries (`two-mode`, `bayespinn.crossings.resonance`); it is not the reference.

    python studies/force_law_check.py --crossings g0-c0 g0-c1 g0-c2 g0-c3 g1-c1 g2-c0 g2-c1 \
        --out reports/paper/diagnostics/force-law-check.json
    python studies/force_law_check.py --crossings g1-c1 g2-c0 --laws two-mode \
        --out reports/paper/diagnostics/force-law-check-two-mode-1.json
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from scipy.optimize import minimize

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402
import crossings as S  # noqa: E402

from bayespinn.crossings import peak  # noqa: E402
from bayespinn.crossings.forward import basis_frequencies  # noqa: E402
from bayespinn.crossings.likelihood import (  # noqa: E402
    FORCE_L_MIN,
    CrossingsLogPosterior,
    inertial_spectral_sd,
    woodbury_loglik,
)
from bayespinn.crossings.resonance import coupled_mode  # noqa: E402
from bayespinn.provenance import provenance  # noqa: E402
from bayespinn.uq.priors import EIPrior, NoisePrior  # noqa: E402

STUDY_SEED, FAMILY_SEED, SNR = 50, 50, 30.0
BAND, BAND2, TAIL_S, PROFILE = (0.3, 2.0), (0.5, 1.5), 1.0, np.linspace(-0.008, 0.008, 9)


def setup(g: int, k: int):
    args = SimpleNamespace(family_seed=FAMILY_SEED, smoke=False, seed=STUDY_SEED)
    gcfg = S.girder_for(args, g)
    d = S.draw(STUDY_SEED, g, k)
    data = S.simulate(S.truth_config(gcfg, d), SNR, d["data_seed"], False)
    cfg = S.stated_config(gcfg, d, True, "fluctuating", "sprung")
    post = CrossingsLogPosterior(
        peak.terms(cfg, data, 8, True), EIPrior.from_spec(cfg.prior),
        NoisePrior.build("vague", np.asarray(data.value, float)),
        zeta_known=cfg.beam.damping_ratio,
        damping_prior=(cfg.prior.damping_median, cfg.prior.damping_log_sd), forces=True,
    )  # fmt: skip
    term = post.terms[0]
    truth = {
        "log_EI": math.log(gcfg.beam.EI),
        "log_zeta": math.log(d["damping_ratio"]),
        f"log_v[{term.name}]": math.log(d["speed"]),
        f"t0[{term.name}]": d["entry_time"],
        f"log_fb[{term.name}]": math.log(d["body_frequency"]),
        f"log_zb[{term.name}]": math.log(d["body_damping"]),
    }
    th = np.zeros(post.layout.dim)
    for n, v in truth.items():
        th[post.layout.index[n]] = v
    return cfg, d, data, post, th


class Fit:
    def __init__(self, cfg, data, post):
        self.cfg, self.post, self.term = cfg, post, post.terms[0]
        rows = self.term.rows
        a_u, a_xx = data.weights
        self.x, self.t = data.x[rows], data.t[rows]
        self.a_u, self.a_xx = np.asarray(a_u)[rows], np.asarray(a_xx)[rows]
        self.ytrue = np.asarray(data.value_true)[rows]

    def __call__(self, theta: np.ndarray, law: str):
        b, veh, term = self.cfg.beam, self.cfg.vehicle, self.term
        p = self.post.unpack(theta[None])
        mu, Rf = term.responses(p, 0)
        v, t0 = float(np.ravel(p["v"][0])[0]), float(np.ravel(p["t0"][0])[0])
        EI, zeta = float(p["EI"][0]), float(p["zeta"][0])
        alpha, _, _ = basis_frequencies(b.length / v, term.model.n_basis)
        r = term.y - mu[0]
        J = veh.loads.size
        w1, k1 = b.natural_frequency(1, EI), math.pi / b.length
        Ta, Tb = t0, t0 + (b.length + float(veh.offsets.max())) / v + TAIL_S
        Lq = (Tb - Ta) / 2
        inside = (self.t >= Ta) & (self.t <= Tb)

        def modal_columns(n: int, w: float, band):
            """Sine basis in time on the span's window for mode n's coordinate, frequencies in band x w."""
            kk = np.arange(1, int(4 * band[1] * w * Lq / math.pi) + 2)
            aq = math.pi * kk / (2 * Lq)
            aq = aq[(aq > band[0] * w) & (aq < band[1] * w)]
            kn = n * k1
            shape = np.sin(kn * self.x) * (self.a_u - self.a_xx * kn**2)
            Rn = shape[:, None] * np.sin(aq[None] * (self.t[:, None] - Ta)) / math.sqrt(Lq)
            return Rn * inside[:, None], aq

        Rq, aq = modal_columns(1, w1, BAND)
        R2, a2 = (
            modal_columns(2, b.natural_frequency(2, EI), BAND2)
            if law == "two-mode"
            else (Rq[:, :0], aq[:0])
        )
        wr, zr = w1, zeta
        if law in ("coupled", "two-mode"):
            fb, zb = float(np.ravel(p["fb"][0])[0]), float(np.ravel(p["zb"][0])[0])
            wr, zr = (float(a[0]) for a in coupled_mode(
                b.length, b.mass_per_length, veh.loads, veh.offsets, EI, zeta, fb, zb))  # fmt: skip

        def spectrum(w, z, a=aq):
            H2 = 1.0 / ((w**2 - a**2) ** 2 + (2 * z * w * a) ** 2)
            return H2 / H2.max()

        H2 = spectrum(wr, zr)

        def basis(h):
            s, ell, sig = np.exp(h[:3])
            dd = inertial_spectral_sd(alpha, np.array([s]), np.array([ell]))
            # the axles' own columns only: the laws compared here have independent axles
            B = (Rf[:, :, : J * dd.shape[1]] * np.tile(dd, (1, J))[:, None, :])[0]
            if law != "today":
                H = spectrum(w1 * math.exp(h[4]), math.exp(h[5])) if law == "free" else H2
                B = np.concatenate([B, Rq * (math.exp(h[3]) * np.sqrt(H))[None]], 1)
            if law == "two-mode":
                H = spectrum(b.natural_frequency(2, EI), math.exp(h[5]), a2)
                B = np.concatenate([B, R2 * (math.exp(h[4]) * np.sqrt(H))[None]], 1)
            return B, sig

        def nll(h):
            if h[1] < math.log(FORCE_L_MIN):
                return 1e10
            if law == "free" and not (-0.7 < h[4] < 0.7 and math.log(1e-3) < h[5] < math.log(0.5)):
                return 1e10
            if law == "two-mode" and not math.log(1e-3) < h[5] < math.log(0.5):
                return 1e10
            B, sig = basis(h)
            ll = -0.5 * r.size * math.log(2 * math.pi * sig**2)
            return -float(ll + woodbury_loglik(r[None], B[None], np.array([sig**2]))[0])

        best = None
        for l0 in (0.15, 0.4):
            for q0 in (np.std(r), 0.1 * np.std(r)):
                h0 = [math.log(0.05), math.log(l0), math.log(np.std(r)), math.log(q0)]
                if law == "free":
                    h0 += [math.log(wr / w1) + 0.05, math.log(max(zr, 0.02))]
                if law == "two-mode":
                    h0 += [math.log(q0), math.log(0.02)]
                o = minimize(nll, h0, method="Nelder-Mead",
                             options=dict(maxiter=4000, xatol=1e-4, fatol=1e-4))  # fmt: skip
                best = o if best is None or o.fun < best.fun else best
        B, sig = basis(best.x)
        w = np.linalg.solve(B.T @ B + sig**2 * np.eye(B.shape[1]), B.T @ r)
        err = float(np.std(mu[0] + B @ w - self.ytrue) / sig)
        self.last = {"fitted": mu[0] + B @ w, "sig": sig, "window": (Ta, Tb)}
        if law == "free":
            wr, zr = w1 * math.exp(best.x[4]), math.exp(best.x[5])
        mode = {"omega_ratio": wr / w1, "damping_ratio": zr} if law != "today" else None
        if law == "two-mode":
            mode["second_mode_damping_ratio"] = math.exp(best.x[5])
        return -float(best.fun), np.exp(best.x), err, int(Rq.shape[1] + R2.shape[1]), mode


LAWS = ("today", "resonant", "coupled", "free", "two-mode")


def check(g: int, k: int, laws=LAWS[:2]) -> dict:
    cfg, d, data, post, th = setup(g, k)
    fit = Fit(cfg, data, post)
    out = {"crossing": f"g{g}-c{k}", "road": d["road"], "n_data": len(data), "laws": {}}
    for law in laws:
        t0 = time.perf_counter()
        ll, h, err, nq, mode = fit(th, law)
        prof = []
        for dl in PROFILE:
            t2 = th.copy()
            t2[0] += dl
            prof.append(fit(t2, law)[0])
        cf = np.polyfit(PROFILE, np.asarray(prof), 2)
        peak = -cf[1] / (2 * cf[0])
        sd = math.sqrt(-1 / (2 * cf[0])) if cf[0] < 0 else math.nan
        out["laws"][law] = {
            "loglik": ll,
            "force_scale": float(h[0]),
            "force_time_scale_s": float(h[1]),
            "fit_error_noise_sd": err,
            "log_EI_peak_pct": 100 * peak,
            "log_EI_sd_pct": 100 * sd,
            "z": peak / sd,
            "profile": [p - max(prof) for p in prof],
            "resonant_columns": nq if law != "today" else 0,
            "resonant_mode": mode,
            "seconds": time.perf_counter() - t0,
        }
        print(f"{out['crossing']} ({d['road']}) {law:9s} loglik {ll:9.1f}  fit error {err:.2f} sd  "
              f"EI peak {100 * peak:+.3f} % (profile sd {100 * sd:.3f} %, z {peak / sd:+.2f})",
              flush=True)  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--crossings", nargs="+", default=["g0-c0"], help="g<G>-c<K> of the study")
    p.add_argument("--laws", nargs="+", default=list(LAWS[:2]), choices=LAWS, help="force laws")
    p.add_argument("--out", type=Path, default=None, help="JSON of the measurements")
    a = p.parse_args(argv)
    todo = []
    for s in a.crossings:
        m = re.fullmatch(r"g(\d+)-c(\d+)", s)
        if not m:
            print(f"error: --crossings: {s!r} is not g<G>-c<K>", file=sys.stderr)
            return 2
        todo.append((int(m[1]), int(m[2])))
    rows = [check(g, k, a.laws) for g, k in todo]
    if a.out:
        doc = {"crossings": rows, "provenance": {
            "command": c.command_line(__file__, sys.argv[1:] if argv is None else argv),
            "seed": STUDY_SEED, **provenance("cpu")}}  # fmt: skip
        a.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = a.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(doc, indent=1))
        tmp.replace(a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
