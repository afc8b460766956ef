"""Draw docs/simulator_benchmark.png: `python docs/simulator_benchmark_figure.py`.

The moving sprung-mass benchmark configuration of docs/simulator.md (Yang & Yau 1997's parameters):
(a) the midspan deflection, (b) the sprung mass's vertical acceleration, each by the simulator (default
settings), by the converged modal series (12 modes), by Biggs' single mode, and (a) by a constant
moving force. The modal solution is the one tests/test_vbi_benchmark.py checks the simulator against;
it is computed here, not read from a paper.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_vbi_benchmark import (  # noqa: E402
    CROSSING,
    INERTIA,
    LOAD,
    SPAN,
    SPEED,
    YOUNG,
    benchmark_beam,
    benchmark_vehicle,
    modal_solution,
    simulated,
)

from bayespinn.config import replace  # noqa: E402

OUT = Path(__file__).with_name("simulator_benchmark.png")


def main(out: Path = OUT) -> None:
    t = np.linspace(0.0, CROSSING, 451)
    beam, veh = benchmark_beam(), benchmark_vehicle()
    mid_ref, acc_ref = modal_solution(12, t)
    mid_1, acc_1 = modal_solution(1, t)
    mid, acc = simulated(beam, veh, t, 192, 8000)
    force = simulated(beam, replace(veh, model="forces"), t, 192, 8000)[0]
    x = SPEED * t
    quasi = (
        LOAD
        * np.where(
            x <= SPAN / 2,
            x * (3 * SPAN**2 - 4 * x**2),
            (SPAN - x) * (3 * SPAN**2 - 4 * (SPAN - x) ** 2),
        )
        / (48 * YOUNG * INERTIA)
    )
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    a = ax[0]
    a.plot(t, 1e3 * mid_ref, "k-", lw=2.5, label="modal series, 12 modes")
    a.plot(t, 1e3 * mid, "C1--", label="simulator (192 elements, 8000 steps)")
    a.plot(t, 1e3 * mid_1, "C2:", lw=1.5, label="single mode (Biggs)")
    a.plot(t, 1e3 * force, "C0-", lw=0.8, label="constant moving force")
    a.plot(t, 1e3 * quasi, "0.6", lw=0.8, ls="-.", label="static")
    a.set(xlabel="t from the entry [s]", ylabel="midspan deflection [mm], down",
          title="(a) midspan deflection")  # fmt: skip
    a.legend(fontsize=8)
    a = ax[1]
    a.plot(t, acc_ref, "k-", lw=2.5, label="modal series, 12 modes")
    a.plot(t, acc, "C1--", label="simulator")
    a.plot(t, acc_1, "C2:", lw=1.5, label="single mode (Biggs)")
    a.set(xlabel="t from the entry [s]", ylabel="sprung mass acceleration [m/s²], down",
          title="(b) the sprung mass's vertical acceleration")  # fmt: skip
    a.legend(fontsize=8)
    fig.suptitle(
        "Moving sprung mass, L = 25 m, EI = 8.32e9 N m², 2303 kg/m; 5750 kg on 1595 kN/m at 100 km/h",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
