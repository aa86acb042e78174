"""The envelope: named manoeuvres, each with its pass rule, on which a stability controller is judged.

FMVSS 126 is one robot steering programme at one speed. A stability controller is worth what it
does on the manoeuvres a car meets: it must do nothing in normal driving, hold the car at the
limit, and never make a manoeuvre worse than the car alone. Every case here is driven with the
ECU in the loop (not told the road) and without control, and judged by :func:`judge`:

* **No harm.** Where the uncontrolled car passes (no cone hit, sideslip below :data:`SLIDE_DEG`),
  the controlled car passes too and its peak sideslip is at most
  ``max(HARM_FACTOR x uncontrolled, uncontrolled + HARM_MARGIN_DEG)``.
* **Quiet in normal driving.** Where the uncontrolled car's lateral acceleration stays below
  :data:`NORMAL_USE` of the road's friction limit ``mu g`` and it does not slide, the law stays
  off: the added steer (command minus driver) stays within :data:`QUIET_STEER_DEG` and the yaw
  moment within :data:`QUIET_YAW_MOMENT`. A disturbance is not normal driving: rejecting a gust or
  the yaw moment of split friction is the law's work (cancelling 1.5 kN of side force takes about
  0.9 deg of steer); the cases of :data:`DISTURBANCES` are judged by the other rules.
* **Stabilises.** Where the uncontrolled car slides past :data:`SLIDE_DEG` (or is lost), the
  controlled car's peak sideslip stays below :data:`HELD_DEG`.
* **Rejects a crosswind.** In a gust, the lateral deviation :data:`GUST_AFTER` s after the gust
  starts is at most :data:`GUST_SHARE` of the uncontrolled car's.

The cases (:func:`cases`): step steer (J-turn) at 60-130 km/h on mu 0.3-1.0, held 3.5 s, and at
100-130 km/h on mu 0.3-0.5 held :data:`HELD_STEP_HOLD` s (a limit turn held until the car slows); a friction drop in a
steady turn; split friction in a straight-line acceleration and in a lane change; lift-off in a
turn; the ISO 3888-1 double lane change at 70 and 90 km/h on mu 0.5 and 0.7 (the path-following
driver); ISO 3888-2 obstacle avoidance and an 18 m slalom with a human driver (reaction delay and
neuromuscular lag: :class:`plants.paths.HumanDriver`), entry speed stepped up; sine with dwell at
60-120 km/h; a crosswind gust; smooth random steering below 4 m/s^2; a car loaded at the rear (the
nominal file unchanged, the two-track only). The step steers begin :data:`STEP_START` s into the run,
after the ECU's filter has settled (a car reaches a test's speed before its manoeuvre). Each case belongs to the ``design`` subset (the design
job's limit constraint) or the ``validation`` subset (reported, never tuned on): :data:`SUBSETS`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from evstab.plants import G, VehicleParams, is_multibody
from evstab.plants.disturbances import Disturbances, Friction, Wind
from evstab.plants.errors import ManeuverError
from evstab.plants.maneuvers import (Maneuver, iso3888_1, iso3888_2, random_steer, sine_lane_change, sine_with_dwell,
                                     slalom, step_steer, steer_for_lateral_acceleration, vehicle_width)

HARM_FACTOR = 1.1
"""Where the car alone passes, the controlled car's peak sideslip may exceed the uncontrolled one's
by this factor ..."""
HARM_MARGIN_DEG = 0.3
"""... or by this much [deg], whichever allows more (a noise-level sideslip of 0.5 deg may become 0.8)."""
SLIDE_DEG = 10.0
"""[deg] Peak sideslip beyond which a car has slid (lost the manoeuvre)."""
HELD_DEG = 5.0
"""[deg] Where the car alone slides, the controlled car's peak sideslip stays below this."""
NORMAL_USE = 0.6
"""A run is normal driving where the car alone stays below this share of the friction limit ``mu g``."""
QUIET_STEER_DEG = 0.25
"""[deg road-wheel] In normal driving the law's added steer stays within this ..."""
QUIET_YAW_MOMENT = 300.0
"""... and its yaw moment within this [N m]."""
GUST_SHARE = 0.5
"""In a crosswind the controlled car's lateral deviation is at most this share of the car alone's ..."""
GUST_AFTER = 2.0
"""... this long [s] after the gust starts."""
HELD_STEP_HOLD = 8.0
"""[s] How long the ``held-step`` cases hold the step steer (the ``step`` cases: 3.5 s)."""
STEP_START = 3.0
"""[s] The step steers' start: the ECU starts with the run at the test speed, and its filter's
kinematic sideslip path waits ``kinematic_settle`` (2 s) after the first GPS fix; a limit manoeuvre
within those 2 s meets the linear model alone (docs/controller.md gives the figures)."""
DISTURBANCES = ("crosswind", "split-mu-accel", "split-mu-lane-change")
"""Case kinds whose cause is the road or the air, not the driver: the quiet rule does not apply."""
OVERHANG = 0.8
"""[m] The body's reach ahead of the front axle and behind the rear one, for cone hits (evstab's
figure for a passenger car: vehicle files give the wheelbase and width, not the length)."""


@dataclass(frozen=True)
class Case:
    """One manoeuvre of the envelope."""

    kind: str
    """``step``, ``held-step``, ``friction-drop``, ``split-mu-accel``, ``split-mu-lane-change``, ``lift-off``,
    ``iso3888-1``, ``iso3888-2``, ``slalom``, ``sine-with-dwell``, ``crosswind``, ``random-steer``, ``loaded``."""
    speed_kmh: float
    mu: float = 1.0
    mu_after: float | None = None
    """The friction after the drop (``friction-drop``) or on the right-hand wheels (``split-mu-*``)."""
    subset: str = "validation"

    @property
    def label(self) -> str:
        mu = f"mu {self.mu:g}"
        if self.kind == "friction-drop":
            mu = f"mu {self.mu:g} -> {self.mu_after:g}"
        elif self.kind.startswith("split-mu"):
            mu = f"mu {self.mu:g} left, {self.mu_after:g} right"
        return f"{self.kind} {self.speed_kmh:.0f} km/h {mu}"

    @property
    def disturbance(self) -> bool:
        """Whether the case's cause is the road or the air (:data:`DISTURBANCES`)."""
        return self.kind in DISTURBANCES

    @property
    def mu_min(self) -> float:
        """The lowest friction anywhere in the run (the limit ``normal driving`` is measured against)."""
        return min(self.mu, self.mu_after if self.mu_after is not None else self.mu)


SUBSETS = ("design", "validation")


def cases(plant: str = "two-track") -> list[Case]:
    """The envelope for a car on ``plant``: ``design`` cases (the design job's constraint) and
    ``validation`` cases (other manoeuvres, speeds and frictions; reported only). The loaded car
    needs a plant whose truth evstab can change (not a multi-body car)."""
    out = [Case("step", kmh, mu, subset="design") for kmh, mu in ((80, 1.0), (80, 0.5))]
    out += [Case("step", kmh, mu) for kmh in (60, 100, 130) for mu in (0.3, 0.5, 0.6, 1.0)]
    out += [Case("held-step", kmh, mu) for kmh, mu in ((100, 0.5), (130, 0.3), (130, 0.5))]
    out += [Case("friction-drop", 80, 1.0, 0.3), Case("friction-drop", 80, 0.8, 0.5)]
    out += [Case("split-mu-accel", 30, 1.0, 0.2), Case("split-mu-lane-change", 80, 1.0, 0.3)]
    out += [Case("lift-off", 80, mu) for mu in (1.0, 0.5)]
    out += [Case("iso3888-1", kmh, mu) for kmh in (70, 90) for mu in (0.5, 0.7)]
    out += [Case("iso3888-2", kmh, 1.0) for kmh in (50, 60, 70, 80)]
    out += [Case("slalom", kmh, 1.0) for kmh in (40, 50, 60)]
    out += [Case("sine-with-dwell", kmh, 1.0) for kmh in (60, 100, 120)]
    out += [Case("crosswind", 100, 1.0), Case("random-steer", 80, 1.0)]
    if not is_multibody(plant):
        out += [Case("loaded", 100, 0.6)]
    return out


GUST_FORCE = 1500.0
"""[N] The crosswind gust (at the centre of gravity, 0.3 m ahead of it: :func:`run_setup`)."""
GUST_START = 2.0


def loaded(p: VehicleParams, extra: float = 150.0, at: float = -0.5) -> VehicleParams:
    """``p`` with ``extra`` kg at ``at`` m behind the rear axle (a laden boot): the mass, the CG and
    the yaw inertia move (parallel-axis theorem, the load a point mass); the tyres' cornering
    stiffness follows the axle loads (constant per unit load)."""
    m0, lf0, lr0 = p.mass, p.lf, p.lr
    x_load = -lr0 - abs(at)  # from the CG, forward positive
    m = m0 + extra
    shift = extra * x_load / m  # the new CG from the old one
    lf, lr = lf0 - shift, lr0 + shift
    iz = p.yaw_inertia + m0 * shift ** 2 + extra * (x_load - shift) ** 2
    wb = lf0 + lr0
    front0, rear0 = m0 * lr0 / wb, m0 * lf0 / wb
    front, rear = m * lr / wb, m * lf / wb
    return dataclasses.replace(p, name=f"{p.name}+{extra:g}kg-rear", mass=m, lf=lf, lr=lr, yaw_inertia=iz,
                               cornering_stiffness_front=p.cornering_stiffness_front * front / front0,
                               cornering_stiffness_rear=p.cornering_stiffness_rear * rear / rear0)


def run_setup(case: Case, p: VehicleParams) -> tuple[Maneuver, Disturbances, VehicleParams | None]:
    """The manoeuvre, the road and, for ``loaded``, the truth parameters (else None) of ``case`` for
    a car whose nominal parameters are ``p``."""
    v = case.speed_kmh / 3.6
    width = vehicle_width(p)
    road = Disturbances(friction=Friction(mu=case.mu))
    truth = None
    if case.kind in ("step", "held-step", "loaded"):
        hold = HELD_STEP_HOLD if case.kind == "held-step" else 3.5
        man = step_steer(v, steer_for_lateral_acceleration(p, v, 1.5 * case.mu * G), start=STEP_START,
                         duration=STEP_START + hold)
        if case.kind == "loaded":
            truth = loaded(p)
    elif case.kind == "friction-drop":
        man = step_steer(v, steer_for_lateral_acceleration(p, v, 0.5 * case.mu * G), start=0.5, rise=0.5,
                         duration=7.0)
        road = Disturbances(friction=Friction(mu=case.mu, mu_after=case.mu_after, change_at=3.0))
    elif case.kind == "split-mu-accel":
        man = dataclasses.replace(step_steer(v, 0.0, duration=6.0), name="split-mu-accel",
                                  speed_profile=lambda t: v + 3.0 * np.clip(np.asarray(t, float) - 1.0, 0.0, None))
        road = Disturbances(friction=Friction(mu=case.mu, mu_left=case.mu, mu_right=case.mu_after))
    elif case.kind == "split-mu-lane-change":
        man = sine_lane_change(v, steer_for_lateral_acceleration(p, v, 3.0), start=1.0, period=3.0, duration=7.0)
        road = Disturbances(friction=Friction(mu=case.mu, mu_left=case.mu, mu_right=case.mu_after))
    elif case.kind == "lift-off":
        steer = step_steer(v, steer_for_lateral_acceleration(p, v, 0.7 * case.mu * G), start=0.5, rise=1.0,
                           duration=7.0)
        man = dataclasses.replace(steer, name="lift-off", coast_from=3.5, events={"lift_off": 3.5})
    elif case.kind == "iso3888-1":
        man = iso3888_1(v, width)
    elif case.kind == "iso3888-2":
        man = iso3888_2(v, width)
    elif case.kind == "slalom":
        man = slalom(v, width)
    elif case.kind == "sine-with-dwell":
        man = sine_with_dwell(v, 6.5 * steer_for_lateral_acceleration(p, v, 0.3 * G))
    elif case.kind == "crosswind":
        man = dataclasses.replace(step_steer(v, 0.0, duration=GUST_START + GUST_AFTER + 1.0), name="crosswind",
                                  events={"gust": GUST_START})
        road = Disturbances(friction=Friction(mu=case.mu),
                            wind=Wind(start=GUST_START, end=GUST_START + 10.0, force=GUST_FORCE,
                                      yaw_moment=0.3 * GUST_FORCE))
    elif case.kind == "random-steer":
        man = random_steer(v, p, ay_max=4.0, seed=7)
    else:
        raise ManeuverError(f"unknown envelope case kind '{case.kind}'")
    return man, road, truth


@dataclass(frozen=True)
class Metrics:
    """What a run did to the car."""

    peak_beta_deg: float
    """Peak |sideslip| [deg] (inf: the car was lost: rolled over or the model diverged)."""
    peak_ay: float
    """Peak |lateral acceleration| [m/s^2]."""
    cones_hit: int
    """Cones inside the body's outline at some instant (0 where the manoeuvre has none)."""
    added_steer_deg: float
    """Peak |the ECU's steer command - the driver's steer| [deg road-wheel] (0 without control)."""
    peak_yaw_moment: float
    """Peak |yaw-moment command| [N m]."""
    deviation_m: float
    """|lateral position change| :data:`GUST_AFTER` s after the gust starts [m] (NaN without a gust)."""

    @property
    def slid(self) -> bool:
        return not self.peak_beta_deg < SLIDE_DEG

    @property
    def passed(self) -> bool:
        return self.cones_hit == 0 and not self.slid


LOST = Metrics(float("inf"), float("nan"), 0, float("nan"), float("nan"), float("nan"))


def cones_hit(x, y, yaw, cones: np.ndarray | None, p: VehicleParams, width: float) -> int:
    """How many of ``cones`` (x, y) the body's outline (the wheelbase plus :data:`OVERHANG` at each end,
    ``width`` wide) covers at some sample of the trajectory (x, y, yaw)."""
    if cones is None or len(cones) == 0:
        return 0
    x, y, yaw = (np.asarray(a, float) for a in (x, y, yaw))
    c, s = np.cos(yaw), np.sin(yaw)
    hit = 0
    for cx, cy in np.asarray(cones, float):
        dx, dy = cx - x, cy - y
        along, across = c * dx + s * dy, -s * dx + c * dy
        inside = (along <= p.lf + OVERHANG) & (along >= -(p.lr + OVERHANG)) & (np.abs(across) <= 0.5 * width)
        hit += bool(np.any(inside))
    return hit


def metrics(r, man: Maneuver, p: VehicleParams) -> Metrics:
    """:class:`Metrics` of a finished run (a :class:`toolkit.loop.simulator.SimResult`)."""
    beta = np.asarray(r.truth["beta"], float)
    if not np.all(np.isfinite(beta)):
        return LOST
    width = vehicle_width(p)
    cmd, drv = r.commands.get("steer_cmd"), r.commands.get("steer_driver")
    added = 0.0 if cmd is None or drv is None else float(np.degrees(np.max(np.abs(cmd - drv))))
    nz = r.commands.get("yaw_moment_cmd", r.commands["yaw_moment"])
    dev = float("nan")
    if "gust" in man.events:
        t0 = man.events["gust"]
        dev = float(abs(np.interp(t0 + GUST_AFTER, r.t, r.truth["y"]) - np.interp(t0, r.t, r.truth["y"])))
    return Metrics(float(np.degrees(np.max(np.abs(beta)))), float(np.max(np.abs(r.truth["ay"]))),
                   cones_hit(r.truth["x"], r.truth["y"], r.truth["yaw"], man.cones, p, width), added,
                   float(np.max(np.abs(nz))), dev)


def judge(ctl: Metrics, none: Metrics, mu: float, disturbance: bool = False) -> list[str]:
    """The envelope's rules broken by a controlled run ``ctl`` against the car alone ``none`` on a road
    whose lowest friction is ``mu``; empty: the run passes. ``disturbance``: the case is one of
    :data:`DISTURBANCES` (a gust is one whatever this says)."""
    broken = []
    if none.passed:
        if not ctl.passed:
            what = f"{ctl.cones_hit} cones hit" if ctl.cones_hit else f"slid ({ctl.peak_beta_deg:.1f} deg)"
            broken.append(f"no harm: {what} where the car alone passes")
        bound = max(HARM_FACTOR * none.peak_beta_deg, none.peak_beta_deg + HARM_MARGIN_DEG)
        if not ctl.peak_beta_deg <= bound:
            broken.append(f"no harm: peak sideslip {ctl.peak_beta_deg:.2f} deg > {bound:.2f} deg "
                          f"(car alone {none.peak_beta_deg:.2f} deg)")
        if none.peak_ay < NORMAL_USE * mu * G and not disturbance and not np.isfinite(none.deviation_m):
            if not ctl.added_steer_deg <= QUIET_STEER_DEG:
                broken.append(f"quiet: added steer {ctl.added_steer_deg:.2f} deg > {QUIET_STEER_DEG:g} deg in normal "
                              f"driving")
            if not ctl.peak_yaw_moment <= QUIET_YAW_MOMENT:
                broken.append(f"quiet: yaw moment {ctl.peak_yaw_moment:.0f} N m > {QUIET_YAW_MOMENT:g} N m in normal "
                              f"driving")
    elif none.slid and not ctl.peak_beta_deg < HELD_DEG:
        broken.append(f"stabilise: peak sideslip {ctl.peak_beta_deg:.1f} deg, not below {HELD_DEG:g} deg "
                      f"(car alone {none.peak_beta_deg:.1f} deg)")
    if np.isfinite(none.deviation_m) and not ctl.deviation_m <= GUST_SHARE * none.deviation_m:
        broken.append(f"crosswind: deviation {ctl.deviation_m:.2f} m > {GUST_SHARE:g} x {none.deviation_m:.2f} m")
    return broken


def run(case: Case, p: VehicleParams, plant: str, *, controller: str | None = "two-dof", seed: int = 0,
        design=None, estimator="dakf") -> Metrics:
    """One run of ``case`` for a car whose ECU believes ``p`` (on a multi-body ``plant`` the truth is
    the package's set; on ``loaded`` the loaded car), controlled (``controller``, the ECU not told
    the road) or not (None). A rolled-over or diverged car is :data:`LOST`."""
    from ..loop.simulator import SimulationError, simulate
    man, road, truth = run_setup(case, p)
    try:
        r = simulate(truth or p, plant, man, disturbances=road, seed=seed, controller=controller,
                     estimator=estimator, design=design, nominal=p if truth is not None else None)
    except SimulationError:
        return LOST
    return metrics(r, man, p)
