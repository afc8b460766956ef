"""Diagnostic (strain case): is a PINN's offset from the reference explained by the Gaussian load or
by the finite-element data? Modal models stand in for a perfect PINN, in seconds per bridge.

    python studies/strain_offset_check.py [--bridges 6] [--case strain] [--out reports/paper/diagnostics]

For bridge i of family seed 0 at 30 dB (the family study's data seed), log EI is fitted by 1-D least
squares, relative to the truth, with
- the point-load modal model (`POINT_MODES` modes; exact static part): what the reference's likelihood sees;
- the Gaussian-load modal model of the fast profile's width beta, divided by its bias factor
  (`pinn.beta.beta_bias_factor`): what a perfect PINN with the beta correction would give;
to three data: the noisy data, the same FE simulation without noise, and the point-load modal prediction
at the true EI. `gauss_minus_point_pct` is what the Gaussian load leaves after its correction; the clean
FE data's `point` fit is the FE truth's own offset, which moves the reference and a PINN alike.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bayespinn import family  # noqa: E402
from bayespinn.data.synthetic import simulate  # noqa: E402
from bayespinn.physics.modal import ModalModel  # noqa: E402
from bayespinn.pinn import Problem, TrainSettings  # noqa: E402
from bayespinn.pinn.beta import POINT_MODES, beta_bias_factor  # noqa: E402

SNR_DB = 30.0


def _fit_log_ratio(model: ModalModel, y: np.ndarray, EI: float) -> float:
    """log(EI_fit / EI) of the least-squares fit of `model` to y."""
    res = minimize_scalar(
        lambda lr: float(np.sum((model.predict(EI * math.exp(lr)) - y) ** 2)),
        bounds=(-0.2, 0.2),
        method="bounded",
        options={"xatol": 1e-10},
    )
    return float(res.x)


def check(index: int, case: str) -> dict:
    b = family.bridge(index, 0, case)
    seq = family.data_seed(0, index)
    noisy, clean = simulate(b.cfg, SNR_DB, seq), simulate(b.cfg, None, seq)
    beta = Problem.from_config(b.cfg, noisy).beta_for(TrainSettings.for_profile("fast").beta_rel)
    a_u, a_xx = noisy.weights
    EI = b.cfg.beam.EI
    point = ModalModel(b.cfg.beam, b.cfg.vehicle, noisy.x, noisy.t, a_u, a_xx, n_modes=POINT_MODES)
    gauss = ModalModel(b.cfg.beam, b.cfg.vehicle, noisy.x, noisy.t, a_u, a_xx, beta=beta)
    log_bf = math.log(beta_bias_factor(b.cfg.beam, b.cfg.vehicle, noisy, beta))
    fits = {}
    for name, y in (
        ("noisy", noisy.value),
        ("clean_fe", clean.value),
        ("clean_modal", point.predict(EI)),
    ):
        lp = _fit_log_ratio(point, y, EI)
        lg = _fit_log_ratio(gauss, y, EI) - log_bf
        fits[name] = {"point": lp, "gauss_corrected": lg, "gauss_minus_point_pct": 100 * (lg - lp)}
    return {
        "bridge": index,
        "case": case,
        "alpha": family.speed_parameter(b.cfg),
        "beta_m": beta,
        "beta_factor": math.exp(log_bf),
        "fits_log_ratio": fits,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bridges", type=int, default=6)
    ap.add_argument("--case", default="strain", choices=("strain", "deflection"))
    ap.add_argument("--out", type=Path, default=ROOT / "reports" / "paper" / "diagnostics")
    a = ap.parse_args(argv)
    rows = []
    for i in range(a.bridges):
        rows.append(check(i, a.case))
        f = rows[-1]["fits_log_ratio"]
        print(
            f"bridge {i}: Gaussian minus point on noisy data {f['noisy']['gauss_minus_point_pct']:+.4f} %, "
            f"FE truth's own offset {100 * f['clean_fe']['point']:+.4f} %",
            flush=True,
        )
    a.out.mkdir(parents=True, exist_ok=True)
    path = a.out / f"offset-checks-{a.case}.json"
    path.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
