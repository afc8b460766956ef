"""The force-law diagnostic's coupled mode (`studies/force_law_check.py:coupled_mode`) against two limits
with closed forms: massless bodies leave the bare girder's first mode, and rigid suspensions add each
body's mass at its axle's mode-shape value (the mode's frequency falls by sqrt(M1 / (M1 + sum m phi^2)))."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from bayespinn.config.bridge import Beam

STUDY_SCRIPT = "force_law_check"  # the `study` fixture (conftest.py) imports it

EI = 5e9
BEAM = Beam(length=20.0, EI=EI, mass_per_length=4000.0)
W1 = (math.pi / BEAM.length) ** 2 * math.sqrt(EI / BEAM.mass_per_length)


def lorry(loads):
    return SimpleNamespace(loads=np.asarray(loads, float), offsets=np.array([0.0, 4.0]))


def test_massless_bodies_leave_the_bare_girder_mode(study):
    w, z = study.coupled_mode(BEAM, lorry([1e-6, 1e-6]), EI, 0.01, 2.5, 0.1)
    assert w == pytest.approx(W1, rel=1e-9) and z == pytest.approx(0.01, rel=1e-6)


def test_rigid_suspensions_add_the_bodies_mass(study):
    loads = np.array([60e3, 90e3])
    veh = lorry(loads)
    w, z = study.coupled_mode(BEAM, veh, EI, 0.01, 2000.0, 1e-4)
    x = BEAM.length / 2 + 2.0 - veh.offsets
    phi = np.sin(math.pi * x / BEAM.length)
    M1 = BEAM.mass_per_length * BEAM.length / 2
    expect = W1 * math.sqrt(M1 / (M1 + np.sum(loads / 9.81 * phi**2)))
    assert w == pytest.approx(expect, rel=1e-3)
    # the negative control: the bare girder's frequency is far outside that tolerance
    assert abs(W1 / expect - 1) > 0.05
