"""Realistic synthetic files: the road spectrum, the `crossing` CSV column, several crossings in one
file, and the dispatch of `simulate` (today's FE path untouched when nothing realistic is asked)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import welch

import bayespinn as bp
from bayespinn import seeding
from bayespinn.config import replace
from bayespinn.data.measurements import Measurements, read_csv
from bayespinn.data.synthetic import ar1_noise, sample_layout, sigma_for_snr, true_values
from bayespinn.errors import InputError
from bayespinn.vbi import VBISettings
from bayespinn.vbi import simulate as vbi_simulate
from bayespinn.vbi.road import DX, band_variance, iso8608_psd, iso8608_road

FAST = VBISettings(n_elements=24, n_steps=600)

#: octave bands [cycles/m] where a 51 m Welch segment resolves the n^-2 spectrum without leakage bias
BANDS = np.array([0.1, 0.2, 0.4, 0.8, 1.6, 2.8])


def band_ratios(grid: np.ndarray, gd0: float, waviness: float = 2.0) -> np.ndarray:
    f, p = welch(grid, fs=1 / DX, nperseg=4096, window="hann", detrend=False)
    out = []
    for a, b in zip(BANDS[:-1], BANDS[1:], strict=True):
        m = (f >= a) & (f < b)
        out.append(np.mean(p[m]) / np.mean(iso8608_psd(f[m], gd0, waviness)))
    return np.array(out)


def test_road_psd_is_iso8608_within_sampling_error():
    """Welch PSD (Hann, 51.2 m segments) of 8 profiles of Gd(n0) = 64e-6 m^3 (class B), averaged per
    octave band over 0.1-2.8 cycles/m, within 6 % of Gd(n0) (n / n0)^-2. The sd of one profile's band
    ratio is 2-5 % (measured over 20 seeds), so of the 8-profile mean under 1.7 %: the tolerance is more
    than 3.5 sd. A profile at the wrong level or waviness fails."""
    gd0 = bp.resolve("strain", {"road": {"roughness": "B"}}).road.roughness
    assert gd0 == 64e-6
    grids = [iso8608_road(gd0, -40.0, 60.0, np.random.SeedSequence(s)).grid for s in range(8)]
    ratios = np.mean([band_ratios(g, gd0) for g in grids], axis=0)
    assert np.all(np.abs(ratios - 1.0) < 0.06), ratios
    # over one whole period the variance is the sum of the cosines' powers, the band's Riemann sum
    assert np.var(grids[0]) == pytest.approx(band_variance(gd0), rel=0.01)
    # negative controls: twice the level, or a waviness of 2.5, are out of the tolerance
    assert np.any(np.abs(np.mean([band_ratios(g, gd0 / 2) for g in grids], 0) - 1) > 0.06)
    assert np.any(np.abs(np.mean([band_ratios(g, gd0, 2.5) for g in grids], 0) - 1) > 0.06)


def test_profile_is_a_function_of_the_seed():
    a = iso8608_road(16e-6, -40.0, 60.0, np.random.SeedSequence(5))
    b = iso8608_road(16e-6, -40.0, 60.0, np.random.SeedSequence(5))
    c = iso8608_road(16e-6, -40.0, 60.0, np.random.SeedSequence(6))
    x = np.linspace(-40, 20, 500)
    assert np.array_equal(a.elevation(x), b.elevation(x))
    assert not np.allclose(a.elevation(x), c.elevation(x))
    # the slope is the elevation's derivative
    h = 1e-4
    num = (a.elevation(x + h) - a.elevation(x - h)) / (2 * h)
    assert np.allclose(a.slope(x), num, atol=1e-6 * np.max(np.abs(num)))


def test_csv_crossing_column_round_trip(tmp_path):
    m = Measurements(
        np.array([1.0, 2.0, 3.0]),
        np.array([0.1, 0.2, 0.3]),
        np.array([1e-3, 2e-3, 3e-3]),
        np.array(["deflection"] * 3),
        np.full(3, np.nan),
        np.array(["", "", ""]),
        None,
        np.array(["a", "b", "a"]),
    )
    p = tmp_path / "m.csv"
    m.to_csv(p)
    assert p.read_text().splitlines()[0].endswith(",crossing")
    r = read_csv(p)
    assert list(r.crossing) == ["a", "b", "a"] and r.crossing_names == ("a", "b")
    assert list(r.select(r.crossing == "a").crossing) == ["a", "a"]
    assert r.with_values(r.value * 2).crossing is r.crossing
    # without the column the file is one crossing
    one = Measurements(m.x, m.t, m.value, m.kind, m.y, m.sensor)
    one.to_csv(p)
    assert "crossing" not in p.read_text().splitlines()[0]
    assert read_csv(p).crossing is None and read_csv(p).crossing_names == ()
    # an empty name is refused, naming the row and the column
    p.write_text("x,t,value,kind,crossing\n1.0,0.1,0.001,deflection,a\n2.0,0.2,0.002,deflection,\n")
    with pytest.raises(InputError) as e:
        read_csv(p)
    assert e.value.field == "m.csv row 3, column crossing"


def crossing_cfg():
    return bp.resolve(
        "strain",
        {
            "vehicle": {"model": "sprung"},
            "road": {"roughness": "B", "approach": 10.0},
            "beam": {"damping_ratio": 0.01},
            "data": {"sample_rate": 50.0},
            "crossing": [
                {"name": "c0"},
                {"name": "c1"},
                {"name": "slow", "speed": 5.0, "entry_time": 0.4},
            ],
        },
    )


def test_several_crossings_in_one_file(tmp_path):
    cfg = crossing_cfg()
    m = vbi_simulate(cfg, 20.0, seed=4, settings=FAST)
    assert m.crossing_names == ("c0", "c1", "slow")
    m.to_csv(tmp_path / "c.csv")
    back = read_csv(tmp_path / "c.csv", length=cfg.beam.length)
    assert np.array_equal(back.crossing, m.crossing) and np.array_equal(back.value, m.value)
    assert np.array_equal(back.t, m.t) and np.array_equal(back.sensor, m.sensor)
    L = cfg.beam.length
    for c in cfg.crossings:
        rows = m.crossing == c.name
        T = c.vehicle.entry_time + c.vehicle.duration(L)
        assert m.t[rows].min() == 0.0 and T - 1 / 50.0 < m.t[rows].max() <= T
        assert np.all(m.value_true[rows & (m.t < c.vehicle.entry_time)] == 0.0)
    # the same vehicle, its own road: c0 and c1 differ; the file is a function of the seed
    a, b = m.value_true[m.crossing == "c0"], m.value_true[m.crossing == "c1"]
    assert a.shape == b.shape and not np.allclose(a, b, rtol=1e-3)
    again = vbi_simulate(cfg, 20.0, seed=4, settings=FAST)
    assert np.array_equal(again.value, m.value)
    # the SNR is over all samples of the file; the noise is the seed's "noise" stream
    sigma = sigma_for_snr(m.value_true, 20.0)
    z = seeding.rng(4, "noise").standard_normal(len(m))
    assert np.allclose(m.value - m.value_true, z * sigma, rtol=0, atol=1e-9 * sigma)


def test_ar1_noise_runs_per_crossing_and_sensor():
    cfg = crossing_cfg()
    cfg = replace(cfg, data=replace(cfg.data, noise_ar1=0.6))
    m = vbi_simulate(cfg, 20.0, seed=4, settings=FAST)
    sigma = sigma_for_snr(m.value_true, 20.0)
    z = seeding.rng(4, "noise").standard_normal(len(m))
    first = m.crossing == "c1"
    expect = ar1_noise(z[first], m.select(first), 0.6) * sigma
    assert np.allclose((m.value - m.value_true)[first], expect, rtol=0, atol=1e-9 * sigma)


def test_simulate_dispatches_realistic_crossings_only():
    cfg = crossing_cfg()
    assert cfg.realistic
    assert bp.resolve("strain", {"vehicle": {"entry_time": 0.5}}).realistic
    assert bp.resolve("strain", {"road": {"roughness": 1e-6}}).realistic
    # today's path, bit for bit, when nothing realistic is asked
    for case in ("deflection", "strain"):
        plain = bp.resolve(case)
        d = bp.simulate(plain, snr_db=20, seed=2)
        lay = sample_layout(plain, 2)
        vt = true_values(plain, lay)
        noise = seeding.rng(2, "noise").standard_normal(vt.size) * sigma_for_snr(vt, 20)
        assert np.array_equal(d.value_true, vt) and np.array_equal(d.value, vt + noise)
        assert d.crossing is None


def test_single_realistic_crossing_has_no_crossing_column_and_starts_before_entry():
    cfg = bp.resolve("deflection", {"vehicle": {"model": "sprung", "entry_time": 0.8}})
    m = bp.simulate(replace(cfg, data=replace(cfg.data, n_points=60)), snr_db=None, seed=1)
    assert m.crossing is None and np.array_equal(m.value, m.value_true)
    assert m.t.max() <= 0.8 + cfg.duration and np.any(m.t < 0.8)
    assert np.all(m.value_true[m.t < 0.8] == 0.0) and np.any(m.value_true > 0)
