"""Beam physics: moving loads, the closed-form modal solution and the finite-element reference."""

from .loads import axle_positions, distributed_load, gaussian_delta, on_span
from .modal import ModalModel, static_unit_deflection, static_unit_moment

__all__ = [
    "ModalModel",
    "axle_positions",
    "distributed_load",
    "gaussian_delta",
    "on_span",
    "static_unit_deflection",
    "static_unit_moment",
]
