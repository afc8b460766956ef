"""Draw docs/simulator.png, the figure of docs/simulator.md: `python docs/simulator_figure.py`.

(a) the constant-force limit against today's FE truth, (b) a sprung truck on a class B road against
constant forces, (c) its axle forces from the approach onward, (d) the road profile's PSD against ISO 8608.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.signal import welch  # noqa: E402

import bayespinn as bp  # noqa: E402
from bayespinn.config import replace  # noqa: E402
from bayespinn.data.synthetic import simulate as fe_simulate  # noqa: E402
from bayespinn.vbi import simulate, simulate_crossing  # noqa: E402
from bayespinn.vbi.crossings import _sub  # noqa: E402
from bayespinn.vbi.road import DX, iso8608_psd, iso8608_road  # noqa: E402

OUT = Path(__file__).with_name("simulator.png")


def main(out: Path = OUT) -> None:
    fig, ax = plt.subplots(2, 2, figsize=(11, 7.5))
    # (a) constant forces: the simulator against the FE truth, gauge S4
    cfg = bp.resolve("strain")
    fe, ours = fe_simulate(cfg, None, seed=0), simulate(cfg, None, seed=0)
    s4 = fe.sensor == "S4"
    a = ax[0, 0]
    a.plot(fe.t[s4], 1e6 * fe.value_true[s4], "k-", lw=2.5, label="FE truth (physics.fem)")
    a.plot(ours.t[s4], 1e6 * ours.value_true[s4], "C1--", label="simulator, forces")
    diff = 1e6 * (ours.value_true[s4] - fe.value_true[s4])
    a.plot(fe.t[s4], 100 * diff, "C3-", lw=0.8, label="difference x 100")
    a.set(xlabel="t [s]", ylabel="strain S4 [µε]", title="(a) constant-force limit, Exeter truck")
    a.legend(fontsize=8)
    # (b) sprung axles on a class B road, 1 % damping, recording from 0.5 s before the entry
    real = bp.resolve(
        "strain",
        {
            "vehicle": {"model": "sprung", "entry_time": 0.5},
            "road": {"roughness": "B"},
            "beam": {"damping_ratio": 0.01},
        },
    )
    sprung = simulate(real, None, seed=0)
    forces = simulate(replace(real, vehicle=replace(real.vehicle, model="forces")), None, seed=0)
    s4 = sprung.sensor == "S4"
    a = ax[0, 1]
    a.plot(forces.t[s4], 1e6 * forces.value_true[s4], "k-", lw=1.5, label="constant forces")
    a.plot(sprung.t[s4], 1e6 * sprung.value_true[s4], "C0-", label="sprung axles, class B road")
    a.axvline(0.5, color="0.6", ls=":", label="entry_time")
    a.set(xlabel="t on the data's clock [s]", ylabel="strain S4 [µε]", title="(b) a real crossing")
    a.legend(fontsize=8)
    # (c) the axle forces of that crossing, from the start on the approach
    cr = simulate_crossing(real, real.vehicle, _sub(0, "road", 0))
    a = ax[1, 0]
    for j in range(cr.force.shape[1]):
        a.plot(cr.t_axle, cr.force[:, j] / real.vehicle.loads[j], lw=0.8, label=f"axle {j + 1}")
    a.axvline(0.5, color="0.6", ls=":")
    a.set(xlabel="t [s]", ylabel="contact force / static load", title="(c) axle forces")
    a.legend(fontsize=8, ncol=2)
    # (d) the road's PSD: Welch over 8 profiles against ISO 8608
    gd0 = real.road.roughness
    ps = []
    for s in range(8):
        f, p = welch(iso8608_road(gd0, -40.0, 60.0, np.random.SeedSequence(s)).grid, fs=1 / DX,
                     nperseg=4096)  # fmt: skip
        ps.append(p)
    m = (f > 0.01) & (f < 2.7)
    a = ax[1, 1]
    a.loglog(f[m], np.mean(ps, axis=0)[m], "C0-", lw=0.8, label="synthesised (Welch, 8 profiles)")
    a.loglog(f[m], iso8608_psd(f[m], gd0), "k--", label="ISO 8608 class B, Gd(n0) (n/n0)^-2")
    a.set(xlabel="n [cycles/m]", ylabel="Gd [m³]", title="(d) road roughness spectrum")
    a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main()
