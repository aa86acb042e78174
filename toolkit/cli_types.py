"""argparse types of the ``evstab`` command line: each parses one option's text or raises
``argparse.ArgumentTypeError`` naming what was expected."""

from __future__ import annotations

import argparse

import numpy as np

from evstab.plants import PLANT_SPECS, get_plant
from evstab.plants.errors import EvstabError


def outage(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--gps-outage expects START:END in seconds, got '{text}'") from None
    if not b > a:
        raise argparse.ArgumentTypeError(f"--gps-outage {text}: END must be after START")
    return a, b


def number(kind: str):
    """argparse type: a finite number, optionally > 0 ('positive') or >= 0 ('nonneg')."""
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
        ok = np.isfinite(v) and (kind == "finite" or (v > 0 if kind == "positive" else v >= 0))
        if not ok:
            want = {"finite": "a finite number", "positive": "a positive number", "nonneg": "a number >= 0"}[kind]
            raise argparse.ArgumentTypeError(f"expected {want}, got '{text}'")
        return v
    return parse


positive, nonneg, finite = number("positive"), number("nonneg"), number("finite")

SPEED_MAX_KMH = 300.0
"""Largest speed [km/h] a command accepts (beyond it the number is a unit mistake, not a car)."""


def speed_kmh(text: str) -> float:
    """argparse type: a speed in km/h, 0-300."""
    v = nonneg(text)
    if v > SPEED_MAX_KMH:
        raise argparse.ArgumentTypeError(f"{v:g} km/h is beyond {SPEED_MAX_KMH:g} km/h: the speed is in km/h")
    return v


def plant(text: str) -> str:
    """argparse type: a plant name (``commonroad-mb:N[:STEER_RATE]`` included), checked by get_plant."""
    try:
        return get_plant(text).name
    except EvstabError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


PLANT_HELP = ("plant: " + ", ".join(PLANT_SPECS) + " (CommonRoad's multi-body car, parameter set N; "
               "commonroad-mb:N:RATE sets its road-wheel steering-rate limit in rad/s, default 1.5; its truth is "
               "the package's set and --vehicle is what estimator and controller believe)")
