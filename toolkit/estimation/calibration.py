"""A calibration carried from one drive to the next: the gyro bias a filter learnt, as a small TOML file that
``evstab estimate --save-calibration`` writes and ``--calibration`` starts the next drive's filter from::

    [meta]
    source = "evstab estimate drive1.csv --vehicle compact-ev ..."

    [gyro]
    bias = 0.00301        # rad/s, the estimate at the drive's last row
    bias_std = 0.00012    # rad/s, its standard deviation

A yaw-rate sensor's bias changes little from one drive to the next (temperature, ageing); a filter that starts
with it known needs no time to learn it, which a cold start at speed does not have. The spread written is the
filter's own; a reader may widen it (the bias may have moved since).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from evstab.plants.errors import DataError

from ..logs.drivelog import atomic_write, read_toml

BIAS_MAX = 0.1
"""[rad/s] A bias beyond this (5.7 deg/s) is not a yaw-rate sensor's: the file is refused."""


def write_calibration(path, bias: float, bias_std: float, source: str) -> None:
    """Write the calibration file (atomically)."""
    text = (f"[meta]\nsource = {json.dumps(source)}\n\n[gyro]\nbias = {float(bias)!r}  # rad/s\n"
            f"bias_std = {float(bias_std)!r}  # rad/s\n")  # a JSON string is a TOML basic string
    atomic_write(path, lambda fh: fh.write(text))


def load_calibration(path) -> tuple[float, float]:
    """``(bias, bias_std)`` [rad/s] from a calibration file; a bad file is refused naming the file and field."""
    path = Path(path)
    doc = read_toml(path, DataError)
    gyro = doc.get("gyro")
    if not isinstance(gyro, dict):
        raise DataError(f"{path}: no [gyro] table (expected 'bias' and 'bias_std' in rad/s)")
    out = []
    for key, lo, hi in (("bias", -BIAS_MAX, BIAS_MAX), ("bias_std", 0.0, BIAS_MAX)):
        v = gyro.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi or \
                (key == "bias_std" and v <= 0):
            raise DataError(f"{path}: [gyro] {key} = {v!r}: expected a number of rad/s in "
                            f"{'(0' if key == 'bias_std' else f'[{lo:g}'}, {hi:g}]")
        out.append(float(v))
    return out[0], out[1]
