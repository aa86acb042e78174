"""A filter design in the simulator's step protocol (for loops closed through an estimator).

``EstimatorComponent(design)`` has ``initial_state()`` and a pure
``step(state, t, signals) -> (state, outputs)``; the signals are the drive-log
names of one sample (``speed``, ``steer``, ``yaw_moment``, ``yaw_rate``,
``gps_course`` (NaN without a fix), ``gps_hdop``, ``gps_sats``, ``ay``) plus ``dt``.
It advances exactly the step the whole-log runner uses (the same compiled casadi
function, one call per sample), so a closed loop and ``evstab estimate`` agree.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import kalman
from .runner import compiled_filter
from .spec import FilterDesign


@dataclass(frozen=True)
class EstimatorComponent:
    design: FilterDesign
    _fn: object = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "_fn", compiled_filter(self.design, "vm").step_fn)

    def initial_state(self, yaw_rate0: float = 0.0) -> np.ndarray:
        from .runner import initial_state
        return initial_state(self.design, yaw_rate0)

    def step(self, state, t, signals):
        course = signals.get("gps_course", np.nan)
        fix = np.isfinite(course)
        hdop, sats = signals.get("gps_hdop", np.nan), signals.get("gps_sats", np.nan)
        heading = signals.get("gps_heading", np.nan)
        gps_speed = signals.get("gps_speed", np.nan)
        vals = {"dt": signals["dt"], "speed": signals["speed"], "steer": signals["steer"],
                "yaw_moment": signals.get("yaw_moment", 0.0), "yaw_rate": signals["yaw_rate"], "fix": float(fix),
                "course": course if fix else 0.0, "hdop": hdop if np.isfinite(hdop) else 1.0,
                "sats": sats if np.isfinite(sats) else 99.0, "ay": signals.get("ay", 0.0),
                "gyro_ok": signals.get("gyro_ok", 1.0), "ax": signals.get("ax", 0.0),
                "gps_speed": gps_speed if np.isfinite(gps_speed) else 0.0,
                "heading": heading if np.isfinite(heading) else 0.0, "heading_valid": float(np.isfinite(heading)),
                "roll_rate": signals.get("roll_rate", 0.0), "gps_roll": 0.0, "gps_roll_valid": 0.0}
        u = np.array([vals[name] for name in kalman.INPUTS])
        zn, y = self._fn(state, u)
        return np.array(zn).ravel(), dict(zip(kalman.OUTPUTS, np.array(y).ravel()))
