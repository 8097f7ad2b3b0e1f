"""Canonical CSV: validation and normalisation only."""

from ..flight import read_flight


def read(path):
    return read_flight(path)
