"""Configuration: frozen, self-validating dataclasses and their resolution.

Resolution order is *preset < TOML file < flags*. The preset is the Exeter bascule bridge east girder of
the paper (Table 3) with the vehicle of the chosen case study. Every value is SI: metres, seconds,
newtons, kilograms, EI in N m^2.

The package's parts: `bridge` (the girder, the vehicle, the road and the crossings), `analysis` (the
data's sampling, the prior, the analysis model and `Config`), `resolution` (the preset, the TOML file and
the SNR flag) and `checks` (the value checks they share). Everything is importable from here.
"""

from dataclasses import replace

from .analysis import (
    AXLE_FORCE_MODELS,
    CASES,
    DAMPING_MODELS,
    EI_FIELDS,
    LOAD_FACTOR,
    NOISE_MODELS,
    SUPPORTS,
    Config,
    DataSpec,
    ModelSpec,
    PriorSpec,
    Sensor,
)
from .bridge import (
    EAST_GIRDER_SHARE,
    EXETER_EI,
    EXETER_SPEED,
    MAX_LOAD_REL_SD,
    MAX_SPEED_SD,
    ROAD_CLASSES,
    TRUCK_AXLE_LOADS,
    TRUCK_SPACINGS,
    VEHICLE_MODELS,
    Axle,
    Beam,
    Crossing,
    Road,
    Vehicle,
    equivalent_ei,
    truck_vehicle,
)
from .checks import _check_int, _check_number
from .resolution import load_toml, parse_snr, preset, resolve, snr_label

__all__ = [
    "AXLE_FORCE_MODELS",
    "CASES",
    "DAMPING_MODELS",
    "EAST_GIRDER_SHARE",
    "EI_FIELDS",
    "EXETER_EI",
    "EXETER_SPEED",
    "LOAD_FACTOR",
    "MAX_LOAD_REL_SD",
    "MAX_SPEED_SD",
    "NOISE_MODELS",
    "ROAD_CLASSES",
    "SUPPORTS",
    "TRUCK_AXLE_LOADS",
    "TRUCK_SPACINGS",
    "VEHICLE_MODELS",
    "Axle",
    "Beam",
    "Config",
    "Crossing",
    "DataSpec",
    "ModelSpec",
    "PriorSpec",
    "Road",
    "Sensor",
    "Vehicle",
    "_check_int",
    "_check_number",
    "equivalent_ei",
    "load_toml",
    "parse_snr",
    "preset",
    "replace",
    "resolve",
    "snr_label",
    "truck_vehicle",
]
