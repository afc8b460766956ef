"""Measurements: the contract's CSV format, validation, and synthetic data at a given SNR."""

from .measurements import Measurements, atomic_write_text, read_csv

__all__ = ["Measurements", "atomic_write_text", "read_csv"]
