"""Faults injected into the ECU's inputs inside the closed loop (between the sensors and the ECU step).

An :class:`EcuFault` names one ECU input (:data:`toolkit.ecu.step.INPUTS`), a kind and a window
``[start, end)`` [s]; :func:`toolkit.loop.simulator.simulate` with ``ecu_fault=`` traces the injector
(:func:`toolkit.loop.closed_loop._inject`) into the loop, whose parameters are run-time, so one compiled
library serves every fault. Kinds:

* ``nan``, ``inf``: the input reads NaN or +infinity;
* ``value``: it reads ``value`` (a spike when the window is one sample, a wrong constant otherwise);
* ``offset``: the reading plus ``value``;
* ``scale``: the reading times ``value``;
* ``stuck``: the reading of the last sample before the window, held;
* ``reset`` (signal ``ecu``): the ECU resets. Through the window it is booting: no step runs, the steer
  actuator takes the driver's command and the motors no yaw moment; at its end the step starts from the
  state ``evstab_init`` sets (the filter and the law from their initial state at speed, the guard with no
  last good values), as the exported C after a watchdog or brown-out reset.

:func:`single_faults` is the set every ECU input meets in ``studies/firmware_faults.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evstab.plants.errors import SettingsError

from ..ecu.step import INPUTS

FAULT_PARAMS = ("set", "value", "add", "gain", "hold")
"""Per ECU input, the run-time parameters of an injected fault (:class:`EcuFault`): inside
the fault's window the input reads ``value`` where ``set``, its value just before the window where ``hold``
(stuck), else ``gain`` times the reading plus ``add``."""

KINDS = ("nan", "inf", "value", "offset", "scale", "stuck", "reset")
ECU = "ecu"
"""The signal a ``reset`` names: the ECU itself."""
OFF = 1e30
"""The window of no fault: it opens at 1e30 s (a finite number: the kernels compare it with the clock)."""


@dataclass(frozen=True)
class EcuFault:
    """One fault on one ECU input (see the module)."""

    signal: str
    kind: str
    start: float
    end: float
    value: float = 0.0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise SettingsError(f"fault kind '{self.kind}' unknown; known: {', '.join(KINDS)}")
        if (self.kind == "reset") != (self.signal == ECU):
            raise SettingsError(f"a reset names the signal '{ECU}' and only a reset does; got kind '{self.kind}' "
                                f"on '{self.signal}'")
        if self.signal not in INPUTS and self.signal != ECU:
            raise SettingsError(f"fault signal '{self.signal}' is not an ECU input; known: {', '.join(INPUTS)}, "
                                f"or '{ECU}' for a reset")
        if not (np.isfinite(self.start) and np.isfinite(self.end) and self.end > self.start >= 0):
            raise SettingsError(f"fault window must be 0 <= start < end, finite; got [{self.start}, {self.end})")

    @property
    def label(self) -> str:
        what = {"nan": "NaN", "inf": "+Inf", "stuck": "stuck", "reset": "reset"}.get(self.kind,
                                                                                    f"{self.kind} {self.value:g}")
        return f"{self.signal} {what}, {1000 * (self.end - self.start):.0f} ms"


def fault_parameters(fault: EcuFault | None) -> list[float]:
    """The loop's run-time fault parameters of ``fault`` (None: no fault): the window, 1 for a reset, then
    :data:`FAULT_PARAMS` per input."""
    start, end = (OFF, OFF) if fault is None else (fault.start, fault.end)
    out = [float(start), float(end), float(fault is not None and fault.kind == "reset")]
    for name in INPUTS:
        p = {"set": 0.0, "value": 0.0, "add": 0.0, "gain": 1.0, "hold": 0.0}
        if fault is not None and name == fault.signal:
            k = fault.kind
            if k in ("nan", "inf", "value"):
                p["set"], p["value"] = 1.0, {"nan": np.nan, "inf": np.inf}.get(k, fault.value)
            elif k == "offset":
                p["add"] = fault.value
            elif k == "scale":
                p["gain"] = fault.value
            else:
                p["hold"] = 1.0
        out += [float(p[k]) for k in FAULT_PARAMS]
    return out


OFFSETS = {"speed": 5.0, "steer": np.radians(2.0), "yaw_rate": 0.1, "ay": 3.0, "steer_cmd_driver": np.radians(2.0),
           "yaw_moment_applied": 1000.0, "gps_course": np.radians(10.0), "mu": -0.5, "wheel_speed_rl": 10.0,
           "wheel_speed_rr": 10.0, "dt": 1e-3}
"""The size of the offset fault on each input (a wrong calibration or a sensor's zero shift)."""
SPIKES = {"speed": 80.0, "steer": 0.8, "yaw_rate": 4.0, "ay": 40.0, "steer_cmd_driver": 0.8,
          "yaw_moment_applied": 5e4, "gps_course": 3.0, "mu": 0.1, "wheel_speed_rl": 400.0, "wheel_speed_rr": 400.0,
          "dt": -1e-3}
"""The value of the one-sample spike on each input: inside its physical range (what a range check alone
lets through), except ``dt`` (a clock that jumps back)."""


def single_faults(start: float, dt: float = 1e-3) -> list[EcuFault]:
    """Every input of :data:`OFFSETS` with: one NaN sample, NaN for 0.5 s, one +Inf sample, one spike
    (:data:`SPIKES`), stuck for 1 s, offset (:data:`OFFSETS`) for 1 s; from ``start``."""
    out = []
    for name in OFFSETS:
        out += [EcuFault(name, "nan", start, start + dt), EcuFault(name, "nan", start, start + 0.5),
                EcuFault(name, "inf", start, start + dt), EcuFault(name, "value", start, start + dt, SPIKES[name]),
                EcuFault(name, "stuck", start, start + 1.0), EcuFault(name, "offset", start, start + 1.0, OFFSETS[name])]
    return out
