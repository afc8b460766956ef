"""The force spectrum's band beyond the law's basis (`bayespinn.crossings.tail`): its columns are the force
basis continued (not a second basis), it reaches the road's shortest wavelength (or a stated band of the
first mode's frequency), the modes within its reach respond dynamically, its
prior level is a sprung body's contact force on an ISO 8608 road (checked against a time integration of
that body on a generated road, apart from the closed form), and the posterior reads its level from data
that carry it, not from data that do not (the negative control)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from gauges import three_gauges
from scipy import signal

from bayespinn.crossings import tail
from bayespinn.crossings.forward import CrossingModel, basis_frequencies
from bayespinn.crossings.likelihood import CrossingTerm, woodbury_loglik
from bayespinn.vbi.road import iso8608_road

L, MU, EI, V, T0 = 20.0, 4000.0, 5e9, 10.0, 0.5
LOADS, OFFSETS = np.array([60e3, 90e3]), np.array([0.0, 4.0])
M = 12


def model(n_basis=M, band=None):
    return CrossingModel(
        L,
        MU,
        LOADS,
        OFFSETS,
        *three_gauges(3.5, 200),
        n_modes=8,
        n_basis=n_basis,
        basis_modes=2,
        band=band,
    )


def params(tail_level: float = 1.0) -> dict:
    one = np.ones(1)
    return {
        "EI": one * EI, "zeta": one * 0.01, "v": [one * V], "t0": [one * T0], "s": one * 0.05,
        "l": one * 0.3, "r": one * 0.5, "fb": [one * 2.5], "zb": [one * 0.1],
        "tail": one * tail_level,
    }  # fmt: skip


BAND = tail.band_of(L, MU, EI, V, M)


def test_the_band_continues_the_basis_to_the_road_reach():
    """band_of's functions start right after the law's n_basis and end at the road's reach v ROAD_N_MAX:
    the last within it, the next beyond it."""
    start, count = BAND
    assert start == M + 1 and count > 10
    alpha, _, _ = basis_frequencies(np.array([L / V]), count + 1, start)
    top = 2 * math.pi * V * tail.ROAD_N_MAX
    assert alpha[0, count - 1] <= top < alpha[0, count]


def test_a_stated_band_spans_its_range_of_the_first_mode(monkeypatch):
    """With BAND set, band_of's functions lie in BAND times the first angular frequency, and one spacing
    beyond either end would not."""
    monkeypatch.setattr(tail, "BAND", (0.5, 1.6))
    start, count = tail.band_of(L, MU, EI, V, M)
    assert count > 10 and start > M
    w1 = (math.pi / L) ** 2 * math.sqrt(EI / MU)
    alpha, _, _ = basis_frequencies(np.array([L / V]), count + 2, start - 1)
    inside = alpha[0, 1:-1] / w1
    assert inside.min() >= tail.BAND[0] and inside.max() <= tail.BAND[1]
    assert alpha[0, 0] / w1 < tail.BAND[0] and alpha[0, -1] / w1 > tail.BAND[1]


def test_the_modes_within_the_band_respond_dynamically():
    """basis_modes counts the modes whose frequency lies within the road's reach: here (20 m, 10 m/s,
    reach 178 rad/s) modes 1-3 (35, 139, 313 rad/s: the first two); never fewer than one, never more than
    the model's modes; a slower vehicle reaches fewer."""
    w = (math.pi * np.arange(1, 4) / L) ** 2 * math.sqrt(EI / MU)
    top = 2 * math.pi * V * tail.ROAD_N_MAX
    assert w[1] <= top < w[2]
    assert tail.basis_modes(L, MU, EI, V, 8) == 2
    assert tail.basis_modes(L, MU, EI, V, 1) == 1
    assert tail.basis_modes(L, MU, EI, 1.0, 8) == 1


def test_band_columns_are_the_longer_basis():
    """Each axle's band columns equal the columns of a basis that runs on to the band's last function, at
    the band's indices; the same columns one index off do not match (the negative control)."""
    start, count = BAND
    _, Rb = model(band=BAND).responses(EI, 0.01, V, T0, basis=True)
    long_m = start + count - 1
    _, Rl = model(n_basis=long_m).responses(EI, 0.01, V, T0, basis=True)
    J = LOADS.size
    assert Rb.shape[2] == J * (M + count)
    for j in range(J):
        got = Rb[0, :, J * M + j * count : J * M + (j + 1) * count]
        want = Rl[0, :, j * long_m + start - 1 : j * long_m + start - 1 + count]
        assert np.allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
        assert np.allclose(Rb[0, :, j * M : (j + 1) * M], Rl[0, :, j * long_m : j * long_m + M])
        shifted = Rl[0, :, j * long_m + start - 2 : j * long_m + start - 2 + count]
        assert not np.allclose(got, shifted, rtol=0.05, atol=0.05 * np.abs(want).max())


def test_the_prior_level_is_a_sprung_body_on_an_iso_road():
    """A body on a spring and damper (2.5 Hz, damping ratio 0.1) driven at 15 m/s over a generated ISO 8608
    road at the class A/B boundary, integrated in time (state space, the road's height and slope as
    inputs): its contact force's PSD per unit static load over 5-20 Hz is the closed form's within 25 %
    in each of three bands (Welch estimate over 60 s: about 5 % sd per band)."""
    v, fb, zb, fs = 15.0, 2.5, 0.1, 400.0
    road = iso8608_road(tail.BOUNDARY_GD0, 0.0, v * 64.0, 7)
    t = np.arange(0.0, 62.0, 1 / fs)
    r, dr = road.elevation(v * t), v * road.slope(v * t)
    wb = 2 * math.pi * fb
    k, c = wb**2, 2 * zb * wb  # per unit mass
    # state (z, z'); z'' = k (r - z) + c (r' - z')
    sys = signal.StateSpace([[0, 1], [-k, -c]], [[0, 0], [k, c]], [[-k, -c]], [[k, c]])
    _, force, _ = signal.lsim(sys, np.stack([r, dr], 1), t)
    rel = force[int(2 * fs) :] / tail.G  # per unit static load, after the start's transient
    f, psd = signal.welch(rel, fs=fs, nperseg=4096)
    closed = 2 * tail.relative_force_sd(2 * math.pi * f[None, 1:], v, fb, zb)[0] ** 2
    for lo, hi in ((5, 8), (8, 12), (12, 20)):
        sel = (f[1:] >= lo) & (f[1:] < hi)
        ratio = psd[1:][sel].mean() / closed[sel].mean()
        assert 0.75 <= ratio <= 1.25, (lo, hi, ratio)
    assert tail.relative_force_sd(np.array([[2 * math.pi * v * 3.0]]), v, fb, zb)[0, 0] == 0.0


@pytest.mark.parametrize("carried", [True, False])
def test_the_posterior_reads_the_band_level(carried):
    """Data whose force carries the band at twice the prior median level: log_tail's profile likelihood
    peaks at log 2 within 0.4; data without the band's content: at least 1.5 below log 2 (the negative
    control)."""
    start, count = BAND
    term = CrossingTerm(
        "c", np.arange(three_gauges(3.5, 200)[0].size), np.zeros(1), model(band=BAND), V, 0.0, T0, 0.0,
        common=True,
    )  # fmt: skip
    _, R = term.responses(params(), 0)
    d = term.column_sds(params(2.0), 0)[0]
    rng = np.random.default_rng(5)
    n_low = d.size - count
    w = rng.standard_normal(d.size) * d
    if not carried:
        w[n_low:] = 0.0
    clean = R[0] @ w
    band_part = R[0, :, n_low:] @ (rng.standard_normal(count) * d[n_low:])
    sig = 0.1 * float(np.std(band_part))
    y = clean + sig * rng.standard_normal(clean.size)
    grid = np.log(2.0) + np.linspace(-4.0, 2.0, 61)
    ll = [
        woodbury_loglik(
            y[None], R * term.column_sds(params(math.exp(g)), 0)[:, None, :], np.array([sig**2])
        )[0]
        for g in grid
    ]
    best = grid[int(np.argmax(ll))]
    if carried:
        assert abs(best - math.log(2.0)) <= 0.4
    else:
        assert best <= math.log(2.0) - 1.5


def test_the_reference_carries_the_band_for_a_sprung_vehicle_only():
    """The reference's law (`peak.terms` with band=None): the band for a sprung vehicle with fluctuating
    forces, none for moving forces (no body to derive its prior from) or constant forces; band=True or
    False overrides it (the timing diagnostic)."""
    import dataclasses

    import bayespinn as bp
    from bayespinn.crossings import peak

    cfg = bp.resolve("strain", {"model": {"axle_forces": "fluctuating"}})
    data = bp.simulate(cfg, 30.0, seed=0)
    sprung = dataclasses.replace(cfg, vehicle=dataclasses.replace(cfg.vehicle, model="sprung"))
    forces = dataclasses.replace(cfg, vehicle=dataclasses.replace(cfg.vehicle, model="forces"))

    def n_band(c, fluctuating=True, band=None):
        return peak.terms(c, data, 8, fluctuating, band=band)[0].model.n_band

    assert n_band(sprung) > 0
    assert n_band(forces) == 0 and n_band(sprung, fluctuating=False) == 0
    assert n_band(forces, band=True) == n_band(sprung) and n_band(sprung, band=False) == 0
