"""The ECU in the stability loop: the firmware's ECU step and its variants (:class:`LoopEcu`).

:func:`toolkit.loop.closed_loop.loop_step` calls :meth:`LoopEcu.step` once per period; ``kind``
``two-dof`` is exactly :func:`toolkit.ecu.step.ecu_step`, what ``evstab export`` prints as C.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

import evstab.controllers.supervisor as sup_mod
import evstab.controllers.two_dof as ctl_mod
from evstab.controllers.allocation import AllocationDesign, brake_yaw_capacity
from evstab.controllers.baselines import STATE as YAW_PI_STATE, yaw_pi_law
from evstab.controllers.brakes import WHEELS
from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import VehicleParams
from evstab.plants.backend import NUMPY
from evstab.plants.errors import EvstabError
from evstab.plants.signals import Layout, Signal

from ..estimation import design_filter
from ..estimation import kalman as kal_mod
from ..estimation.spec import FilterDesign
from ..ecu import guard as guard_mod
from ..ecu.step import (CONTROL_STATE, FIRMWARE_METHODS, INPUTS as ECU_INPUTS, OUTPUTS as ECU_OUTPUTS, EcuDesign,
                        commanded_moment, control_start, ecu_control, ecu_estimate, rear_torques, restart,
                        with_authority)

CONTROLLERS = ("none", "yaw-pi", "two-dof", "two-dof-true")


class LoopError(EvstabError, ValueError):
    """A loop was asked for something it cannot run (named in the message)."""


# ------------------------------------------------------------------------ the ECU in the loop
@dataclass(frozen=True)
class LoopEcu:
    """What the loop runs as its ECU.

    ``kind``:

    * ``two-dof`` — the firmware's ECU step (:func:`toolkit.ecu.step.ecu_step`): what
      ``evstab export`` prints as C;
    * ``none`` — the same filter (its estimates are logged), the driver's steer passed through,
      no yaw moment;
    * ``yaw-pi`` — the same filter, yaw-rate PI on the direct yaw moment
      (:func:`controllers.baselines.yaw_pi_law`), the driver's steer;
    * ``two-dof-true`` — the 2-DOF law on the true sideslip and yaw rate (no filter): the
      controller's best case;
    * ``driver`` — no ECU and no actuators: the driver's steer straight to the plant.
    """

    kind: str
    ecu: EcuDesign | None = None

    def __post_init__(self):
        if self.kind not in CONTROLLERS + ("driver",):
            raise LoopError(f"unknown controller '{self.kind}'; known: {', '.join(CONTROLLERS)}")
        if self.kind != "driver" and self.ecu is None:
            raise LoopError(f"controller '{self.kind}' needs an ECU design")

    @property
    def has_filter(self) -> bool:
        return self.kind in ("two-dof", "none", "yaw-pi")

    @property
    def design(self) -> EcuDesign:
        """The ECU design every kind but ``driver`` runs."""
        if self.ecu is None:
            raise LoopError(f"the '{self.kind}' ECU runs no ECU design")
        return self.ecu

    @property
    def sizes(self) -> tuple[int, int]:
        """(filter state, controller state) sizes; the controller's part ends with the input guard's state."""
        if self.kind == "driver":
            return 0, 0
        ne = self.design.layout.index("controller") if self.has_filter else 0
        nc = len(YAW_PI_STATE) if self.kind == "yaw-pi" else len(ctl_mod.STATE) + len(sup_mod.STATE)
        return ne, nc + guard_mod.STATE.size

    @property
    def guard_slice(self) -> slice:
        """Where the input guard's state sits in this ECU's state: the end of the controller's part."""
        ne, nc = self.sizes
        return slice(ne + nc - guard_mod.STATE.size, ne + nc)

    @property
    def n_state(self) -> int:
        return sum(self.sizes)

    @property
    def layout(self) -> Layout:
        """The loop ECU's state: the filter's part, then the controller's (law and supervisor, or the yaw PI)."""
        ne, nc = self.sizes
        return Layout("loop ECU state", [Signal("filter", "-", "the filter's state", ne),
                                         Signal("control", "-", "the controller's state", nc)])

    def calibration_names(self) -> tuple[str, ...]:
        return () if self.ecu is None else tuple(c.name for c in self.ecu.calibration())

    def calibration_values(self) -> np.ndarray:
        return np.zeros(0) if self.ecu is None else np.array([c.value for c in self.ecu.calibration()])

    def initial_state(self) -> np.ndarray:
        return np.asarray(self.start_state(self.calibration_values()), float).reshape(-1)

    def start_state(self, cal, o=NUMPY):
        """The state at power-up (``evstab_init``'s) with calibration ``cal`` (numbers or symbols): the filter's
        initial state, the law's and the supervisor's (:func:`control_start`: the supervisor starts from a
        calibration), the guard's."""
        ne, nc = self.sizes
        if self.kind == "driver":
            return np.zeros(0)
        parts = []
        if ne:
            parts.append(kal_mod.initial_state(self.design.filter, 0.0, 0.0))
        if self.kind == "yaw-pi":
            parts.append(np.zeros(nc - guard_mod.STATE.size))
        else:
            parts.append(control_start(self._bound(cal), o))
        parts.append(guard_mod.initial_state())
        return o.concat(parts)

    def _bound(self, cal) -> EcuDesign:
        """The ECU design with calibration values ``cal`` (numbers or symbols)."""
        return self.design.bind([cal[i] for i in range(len(self.calibration_names()))])

    def step(self, z, u, truth: dict, cal, o=NUMPY):
        """``(z, u) -> (z_next, y)`` with ``u`` per the ECU's inputs and ``y`` per its outputs;
        ``cal`` the calibration values (numbers or symbols); ``truth`` is read by ``two-dof-true`` only."""
        d = self._bound(cal)
        # the input guard first (toolkit.ecu.guard), as in the ECU step
        ne = self.sizes[0]
        gs = self.guard_slice
        zg, raw = z[gs], ECU_INPUTS.as_dict(u)
        # the loop's calibration is a sweep's run-time input, which the design explores beyond the A2L's limits:
        # it is not checked here (the exported step checks its own, toolkit.ecu.step.ecu_guard)
        # the law's authority of the last period (the supervisor's blend; a yaw-pi law acts throughout: 1)
        blend = z[ne + ctl_mod.STATE.size + sup_mod.STATE.index("blend")] if self.kind != "yaw-pi" else 1.0
        zg, clean = guard_mod.guard(d.guard, zg, raw, d.filter.dt_nominal, d.wheel_radius, o,
                                    track_rear=d.track_rear, law_blend=blend)
        u = ECU_INPUTS.pack(clean, o)
        g = ECU_INPUTS.as_dict(u)
        zero = 0.0 * g["dt"]
        z_f = z[self.layout.slot("filter")] if ne else None
        z_c = z[ne:gs.start]
        # what a restart sets: the calibrated initial state (the supervisor starts from mu_max, a calibration)
        z_c0 = np.zeros(gs.start - ne) if self.kind == "yaw-pi" else control_start(d, o)
        if ne:
            z_f, z_c, broken = restart(z_f, z_c, zg, kal_mod.initial_state(d.filter, 0.0, 0.0), z_c0, o)
        else:
            _, z_c, broken = restart(zero, z_c, zg, 0.0, z_c0, o)
        if self.has_filter:
            z_est_n, est = ecu_estimate(d, z_f, u, o)
        else:
            z_est_n = None
            est = {"beta": truth["beta"], "yaw_rate": truth["yaw_rate"], "yaw": truth["yaw"], "d1": zero,
                   "d2": zero, "gyro_bias": zero, "beta_std": zero, "gps_used": zero, "beta_telemetry": truth["beta"]}
        z_ctl = z_c
        if self.kind == "yaw-pi":
            sig = ctl_mod.SIGNALS.pack(o=o, speed=g["speed"], steer_driver=g["steer_cmd_driver"], beta=est["beta"],
                                       yaw_rate=est["yaw_rate"], d1=est["d1"], d2=est["d2"], mu=g["mu"],
                                       steer_limited=g["steer_limited"], yaw_moment_limited=g["yaw_moment_limited"],
                                       limit_share=zero)
            z_ctl_n, c_y = yaw_pi_law(d.controller, z_ctl, sig, o)
            c = ctl_mod.OUTPUTS.unpack(c_y)
            t_rl, t_rr = rear_torques(d, c.yaw_moment, o)
            y = ECU_OUTPUTS.pack(o=o, **{k: est[k] for k in ("beta", "yaw_rate", "yaw", "d1", "d2", "gyro_bias",
                                                             "beta_std", "gps_used", "beta_telemetry")},
                                 steer_cmd=c.steer, yaw_moment_cmd=c.yaw_moment, torque_rl=t_rl, torque_rr=t_rr,
                                 beta_ref=c.beta_ref, yaw_rate_ref=c.yaw_rate_ref, active=1.0 + zero, drive_share=1.0 + zero,
                                 mu_est=g["mu"],
                                 fault_word=zero, bad_samples=zero, steer_correction=zero,
                                 **{f"brake_pressure_{w}": o.fmax(g["brake_pressure_driver"], 0.0)
                                    for w in WHEELS}, yaw_moment_brakes=zero)
        else:
            z_ctl_n, y = ecu_control(d, z_ctl, u, est, o, guard_mod.STATE.unpack(zg).restart)
            if self.kind == "none":  # pass the driver through; keep the reference for comparison
                ys = ECU_OUTPUTS.as_dict(y)
                ys["steer_cmd"] = g["steer_cmd_driver"]
                for name in ("yaw_moment_cmd", "torque_rl", "torque_rr", "yaw_moment_brakes"):
                    ys[name] = zero
                for w in WHEELS:
                    ys[f"brake_pressure_{w}"] = o.fmax(g["brake_pressure_driver"], 0.0)
                ys["drive_share"] = 1.0 + zero
                y = ECU_OUTPUTS.pack(ys, o)
                parts = CONTROL_STATE.as_dict(z_ctl_n)
                law = ctl_mod.STATE.as_dict(parts["controller"])
                law["xi_beta"] = law["xi_yaw_rate"] = zero
                z_ctl_n = CONTROL_STATE.pack(o=o, controller=ctl_mod.STATE.pack(law, o),
                                                supervisor=parts["supervisor"])
        y = with_authority(y, u, zg, broken, o)
        # the guard compares the next period's applied yaw moment with this period's command
        z_ctl_n = o.concat([z_ctl_n, guard_mod.with_command(zg, commanded_moment(d, ECU_OUTPUTS.as_dict(y)), o)])
        z_next = z_ctl_n if z_est_n is None else o.concat([z_est_n, z_ctl_n])
        return z_next, y


def loop_ecu(kind: str, nominal: VehicleParams, *, dt: float = 1e-3, estimator: str | FilterDesign = "dakf",
             latency: float = 0.0, design: TwoDofDesign | EcuDesign | None = None,
             allocation: str | AllocationDesign | None = None) -> LoopEcu:
    """The ECU a loop runs: ``design`` if it is an :class:`EcuDesign` (a design folder's, say),
    else the firmware ECU made of ``estimator`` (a method designed for ``nominal`` with the GPS
    ``latency`` it compensates, or a designed filter) and ``design`` (default seed 003's gains),
    on the speed schedule of ``nominal``. ``allocation``: how the yaw moment is shared with the friction brakes
    (:mod:`controllers.allocation`: a mode of ``nominal``'s allocation, or a design; None: the motors alone; see
    :func:`with_allocation`)."""
    if kind == "driver":
        return LoopEcu("driver")
    if kind not in CONTROLLERS:
        raise LoopError(f"unknown controller '{kind}'; known: {', '.join(CONTROLLERS)}")
    alloc = AllocationDesign.from_vehicle(nominal, allocation) if isinstance(allocation, str) else allocation
    if isinstance(design, EcuDesign):
        return LoopEcu(kind, design if alloc is None else with_allocation(design, alloc))
    filt = estimator if isinstance(estimator, FilterDesign) else None
    if filt is None:
        if estimator not in FIRMWARE_METHODS:
            raise LoopError(f"the loop runs the ECU step, whose filter is one of {', '.join(FIRMWARE_METHODS)}; "
                            f"got estimator '{estimator}' (other methods run on logs: evstab estimate)")
        filt = design_filter(estimator, nominal, dt=dt, latency=latency, control=True)
    ctl = design if design is not None else TwoDofDesign(nominal.as_nominal(), dt=dt)
    ctl.params.require("track_rear", "wheel_radius", "max_motor_torque", model="the stability loop's ECU "
                       "(yaw-moment split over the rear motors)")
    ecu = EcuDesign.from_designs(filt, ctl)
    return LoopEcu(kind, ecu if alloc is None else with_allocation(ecu, alloc))


def with_allocation(ecu: EcuDesign, alloc: AllocationDesign) -> EcuDesign:
    """``ecu`` sharing its yaw moment as ``alloc`` says: the law may ask what the brakes make at ``mu_max``
    (:func:`controllers.allocation.brake_yaw_capacity`; in a blend besides the motors' ``nz_max``), and in
    ``brakes`` mode it has no steer correction (a conventional ESC: ``steer_authority`` 0). ``motors``: the
    allocation alone is set (the law as it is)."""
    c = ecu.controller
    if alloc.mode == "motors":
        return dataclasses.replace(ecu, allocation=alloc)
    conventional = alloc.mode == "brakes"
    cap = brake_yaw_capacity(alloc, c.mu_max) + (0.0 if conventional else c.nz_max)
    ctl = dataclasses.replace(c, yaw_moment_max=cap, steer_authority=0.0 if conventional else c.steer_authority)
    return dataclasses.replace(ecu, controller=ctl, allocation=alloc)
