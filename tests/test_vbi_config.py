"""Configuration keys of real crossings: [vehicle] model/body/entry keys, [road], [[crossing]]."""

from __future__ import annotations

import pytest

import bayespinn as bp
from bayespinn.config import ROAD_CLASSES, Crossing, Road, Vehicle, preset
from bayespinn.errors import InputError


def test_defaults_are_the_contracts():
    v = Vehicle()
    assert (v.model, v.body_frequency, v.body_damping) == ("forces", 2.5, 0.1)
    assert (v.speed_sd, v.entry_time, v.entry_time_sd) == (0.0, 0.0, 0.0)
    assert Road() == Road(0.0, 30.0)
    cfg = preset("strain")
    assert cfg.crossings == () and not cfg.realistic


def test_keys_parse_and_crossings_inherit_vehicle():
    cfg = bp.resolve(
        "strain",
        {
            "vehicle": {"model": "sprung", "entry_time": 1.5, "body_frequency": 3.0},
            "road": {"roughness": "b", "approach": 20.0},
            "crossing": [{"name": "a", "speed": 7.0, "entry_time_sd": 0.1}, {"speed_sd": 0.01}],
        },
    )
    assert cfg.road.roughness == ROAD_CLASSES["B"] == 64e-6 and cfg.road.approach == 20.0
    a, b = cfg.crossings
    assert isinstance(a, Crossing) and (a.name, b.name) == ("a", "c1")
    assert a.vehicle.speed == 7.0 and a.vehicle.entry_time_sd == 0.1
    assert a.vehicle.model == "sprung" and a.vehicle.body_frequency == 3.0  # from [vehicle]
    assert b.vehicle.speed == cfg.vehicle.speed and b.vehicle.speed_sd == 0.01
    assert len(a.vehicle.axles) == 4  # the truck's axles carry over
    assert cfg.realistic
    d = cfg.to_dict()
    assert d["road"] == {"roughness": 64e-6, "approach": 20.0}
    assert [c["name"] for c in d["crossings"]] == ["a", "c1"]
    assert bp.resolve("strain", {"road": {"roughness": 2e-5}}).road.roughness == 2e-5


def test_identity_and_manifest_unchanged_at_defaults():
    cfg = preset("deflection")
    ident = cfg.identity()
    assert "road" not in ident and "crossings" not in ident
    assert set(ident["vehicle"]) == {"speed", "axles"}
    assert "road" not in cfg.to_dict() and "model" not in cfg.to_dict()["vehicle"]


@pytest.mark.parametrize(
    "doc, field",
    [
        ({"vehicle": {"model": "rigid"}}, "vehicle.model"),
        ({"vehicle": {"body_frequency": 0.0}}, "vehicle.body_frequency"),
        ({"vehicle": {"body_damping": 1.0}}, "vehicle.body_damping"),
        ({"vehicle": {"speed_sd": -0.1}}, "vehicle.speed_sd"),
        ({"vehicle": {"speed_sd": 0.5}}, "vehicle.speed_sd"),
        ({"vehicle": {"entry_time": -1.0}}, "vehicle.entry_time"),
        ({"vehicle": {"entry_time_sd": "x"}}, "vehicle.entry_time_sd"),
        ({"road": {"roughness": "E"}}, "road.roughness"),
        ({"road": {"roughness": -1e-6}}, "road.roughness"),
        ({"road": {"approach": -1.0}}, "road.approach"),
        ({"road": {"bumps": 1}}, "road.bumps"),
        ({"crossing": [{"name": "a"}, {"name": "a"}]}, "crossing.name"),
        ({"crossing": [{"speed": 0.0}]}, "crossing c0: vehicle.speed"),
        ({"crossing": [{"colour": 1}]}, "crossing.colour"),
        ({"crossing": 3}, "[[crossing]]"),
    ],
)
def test_bad_values_name_the_field(doc, field):
    with pytest.raises(InputError) as e:
        bp.resolve("strain", doc)
    assert e.value.field == field
