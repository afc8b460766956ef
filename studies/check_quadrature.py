"""Check a `bayespinn run` folder's EI posteriors against an exact grid-quadrature posterior.

The quadrature is computed independently of the run's samplers, from the run's own ``data.csv`` and its
recorded configuration: the modal model (40 modes) on a fine grid of log EI, sigma integrated out
analytically under the log-uniform (Jeffreys) prior of the default ``--noise-prior vague``, times the
log-normal EI prior. For every method in ``summary.json`` it prints the mean difference in quadrature sds,
the sd ratio, and the sampler's R-hat and bulk ESS, and exits 1 when the modal reference misses the
acceptance bands of the reference posterior (|dmean| <= 0.15 sd, sd within 10 %, R-hat <= 1.01,
ESS >= 400).

    python studies/check_quadrature.py reports/runs/deflection-snr10-seed5 [--config bridge.toml]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy import stats

from bayespinn.config import resolve
from bayespinn.data.measurements import read_csv
from bayespinn.physics.modal import ModalModel

MEAN_TOL_SD, SD_TOL_REL, RHAT_MAX, ESS_MIN = 0.15, 0.10, 1.01, 400


def grid_posterior(cfg, data, half_width: float = 0.3, n: int = 6001) -> tuple[float, float]:
    """(mean, sd) of EI [N m^2] by quadrature on log EI within +-half_width of the MAP region."""
    m = ModalModel(cfg.beam, cfg.vehicle, data.x, data.t, *data.weights, n_modes=40)

    def logpost(le):
        rss = np.concatenate(
            [
                np.sum((data.value[None] - m.predict(np.exp(c))) ** 2, 1)
                for c in np.array_split(le, max(1, le.size // 200))
            ]
        )
        return stats.norm.logpdf(
            le, math.log(cfg.prior.EI_median), cfg.prior.EI_log_sd
        ) - 0.5 * data.value.size * np.log(rss)

    coarse = np.linspace(math.log(cfg.prior.EI_median) - 3, math.log(cfg.prior.EI_median) + 3, 1201)
    centre = coarse[int(np.argmax(logpost(coarse)))]
    le = centre + np.linspace(-half_width, half_width, n)
    lp = logpost(le)
    w = np.exp(lp - lp.max())
    if w[0] > 1e-12 or w[-1] > 1e-12:
        raise SystemExit(
            f"quadrature grid +-{half_width} in log EI does not hold the posterior; widen --half-width"
        )
    w /= w.sum()
    EI = np.exp(le)
    mean = float(np.sum(w * EI))
    return mean, float(np.sqrt(np.sum(w * (EI - mean) ** 2)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="a bayespinn run folder (summary.json, data.csv)")
    ap.add_argument("--config", type=Path, default=None, help="the TOML the run was given, if any")
    ap.add_argument(
        "--case", default=None, help="deflection or strain (default: from summary.json)"
    )
    ap.add_argument("--half-width", type=float, default=0.3)
    a = ap.parse_args(argv)
    summary = json.loads((a.run / "summary.json").read_text())
    case = a.case or summary.get("case", "deflection")
    cfg = resolve(case, a.config)
    data = read_csv(a.run / "data.csv")
    if summary.get("truth", {}).get("EI") not in (None, cfg.beam.EI):
        print(
            f"warning: the run's true EI {summary['truth']['EI']} differs from the config's {cfg.beam.EI}"
        )
    mean, sd = grid_posterior(cfg, data, a.half_width)
    print(f"quadrature: EI mean {mean:.6e} N m^2, sd {sd:.4e} ({100 * sd / mean:.3f} %)")
    ok = True
    for name, m in summary["methods"].items():
        dm = (m["EI"]["mean"] - mean) / sd
        ratio = m["EI"]["sd"] / sd
        diag = m.get("diagnostics", {})
        print(
            f"{name:12s} dmean/sd {dm:+.3f}  sd ratio {ratio:.3f}  R-hat {diag.get('rhat', float('nan')):.4f}  "
            f"ESS bulk {diag.get('ess_bulk', float('nan')):.0f}  runtime {m.get('runtime_s', float('nan')):.1f} s"
        )
        if name == "modal_mcmc":
            ok = (
                abs(dm) <= MEAN_TOL_SD
                and abs(ratio - 1) <= SD_TOL_REL
                and diag.get("rhat", 9) <= RHAT_MAX
                and diag.get("ess_bulk", 0) >= ESS_MIN
            )
            print(
                f"modal reference {'meets' if ok else 'MISSES'} the acceptance "
                f"(|dmean| <= {MEAN_TOL_SD} sd, sd within {100 * SD_TOL_REL:.0f} %, R-hat <= {RHAT_MAX}, ESS >= {ESS_MIN})"
            )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
