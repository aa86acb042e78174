"""Shared fixtures. Every tolerance in this suite has its reason next to it."""

import numpy as np
import pytest

from plants import load_vehicle

VEHICLES = ("micro-ev", "sedan-000", "compact-ev")


@pytest.fixture(params=VEHICLES)
def vehicle(request):
    return load_vehicle(request.param)


@pytest.fixture
def compact():
    return load_vehicle("compact-ev")


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)
