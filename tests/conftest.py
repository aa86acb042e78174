"""Shared fixtures. Every tolerance in this suite has its reason next to it."""

import numpy as np
import pytest

from evstab.plants import load_vehicle

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


@pytest.fixture(scope="session")
def quick_design_dir(tmp_path_factory):
    """``evstab design --quick`` on compact-ev, run once for every test that needs a real design folder."""
    from evstab.toolkit.cli import main
    out = tmp_path_factory.mktemp("quick_design")
    assert main(["design", "--vehicle", "compact-ev", "--out", str(out), "--quick", "--no-progress"]) == 0
    return out
