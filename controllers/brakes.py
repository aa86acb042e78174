"""Friction brakes at every wheel: the hydraulic unit's pressure and the torque it makes.

Each wheel brake's pressure ``p`` [Pa] follows its command ``p_cmd`` (held within ``[0,
brake_pressure_max]``) as a first-order lag of time constant ``brake_tau``, discretised exactly over
the period (``p + (1 - exp(-dt / tau)) (p_cmd - p)``), and its change over one period is held within
``brake_build_rate dt`` up and ``brake_release_rate dt`` down (the pump builds pressure, the outlet
valves release it, each at a largest rate). The torque it makes is ``brake_gain_front`` or
``brake_gain_rear`` times the pressure [N m]; the plants apply it against the wheel's spin
(:func:`plants.two_track.brake_torque`). Pressures are in pascal (1 bar = 1e5 Pa), as every quantity
inside evstab is SI.

The vehicle file gives the six numbers (:data:`FIELDS`); the bundled files state where theirs come
from. One step is :func:`brake_law`, numpy or casadi, like :func:`controllers.actuators.actuator_law`.
"""

from __future__ import annotations

import numpy as np

from evstab.plants import VehicleParams
from evstab.plants.backend import NUMPY
from evstab.plants.signals import Layout, Signal

WHEELS = ("fl", "fr", "rl", "rr")
FIELDS = ("brake_gain_front", "brake_gain_rear", "brake_pressure_max", "brake_tau", "brake_build_rate",
          "brake_release_rate")
"""The vehicle-file fields the brakes need (:class:`plants.params.VehicleParams`)."""

STATE = Layout("brake state", [Signal(f"pressure_{w}", "Pa", f"brake pressure at the {w} wheel") for w in WHEELS])
COMMANDS = Layout("brake commands", [Signal(f"pressure_cmd_{w}", "Pa", f"brake pressure asked at the {w} wheel")
                                     for w in WHEELS])
OUTPUTS = Layout("brake outputs", [
    *(Signal(f"brake_{w}", "N m", f"brake torque at the {w} wheel") for w in WHEELS),
    Signal("brake_limited", "-", "1 while a wheel's pressure was held by a limit (range or rate)"),
])


def gains(p: VehicleParams) -> tuple[float, float, float, float]:
    """Torque per pascal at (FL, FR, RL, RR) [N m/Pa]; a :class:`ParameterError` naming the fields the
    vehicle file lacks."""
    if hasattr(p, "require"):  # a symbolic view of the fields (a traced loop) has been checked where it was made
        p.require(*FIELDS, model="the friction brakes")
    return (p.brake_gain_front, p.brake_gain_front, p.brake_gain_rear, p.brake_gain_rear)  # type: ignore[return-value]


def brake_law(p: VehicleParams, z, cmd, dt, o=NUMPY):
    """One period of the four wheel brakes: ``(z, cmd) -> (z_next, out)`` (:data:`STATE`,
    :data:`COMMANDS`, :data:`OUTPUTS`), ``dt`` [s] the period."""
    k = gains(p)
    z_next, torques, limited = [], [], []
    lag = 1.0 - o.exp(-dt / p.brake_tau)
    up, down = p.brake_build_rate * dt, p.brake_release_rate * dt
    for i in range(4):
        asked = cmd[i]
        target = o.fmin(o.fmax(asked, 0.0), p.brake_pressure_max)
        move = lag * (target - z[i])
        held = o.fmin(o.fmax(move, -down), up)
        pn = z[i] + held
        z_next.append(pn)
        torques.append(k[i] * pn)
        limited.append(o.fmax((asked != target) * 1.0, (held != move) * 1.0))
    out = OUTPUTS.pack(o=o, **{f"brake_{w}": t for w, t in zip(WHEELS, torques)},
                       brake_limited=o.fmax(o.fmax(limited[0], limited[1]), o.fmax(limited[2], limited[3])))
    return STATE.pack(o=o, **{f"pressure_{w}": v for w, v in zip(WHEELS, z_next)}), out


def initial_state() -> np.ndarray:
    """Brakes released."""
    return STATE.zeros()
