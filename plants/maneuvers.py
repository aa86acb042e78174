"""Driving manoeuvres with exact timing and geometry.

A :class:`Maneuver` is either open-loop (a steer profile of time) or closed-loop
(a path followed by :class:`plants.paths.PathDriver`). Speeds are in m/s and
angles are front road-wheel angles in rad; positive steer turns left (ISO 8855).

* ``sine-lane-change`` (seed 003 sec. VI): one full sine period of steer.
* ``step-steer``: ramp to the amplitude in ``rise`` s, then hold (ISO 7401 style).
* ``ramp-steer``: steer rising linearly at a constant rate (ISO 4138 / the FMVSS 126
  slowly increasing steer).
* ``constant-radius``: follow a circle (ISO 4138 constant radius) with the driver.
* ``sine-with-dwell`` (FMVSS 126 S7.9): 0.7 Hz sine; the dwell of 500 ms begins at
  the second peak; peaks at T/4 = 0.357 s and 3T/4 = 1.071 s after the start, back
  at zero at 3T/4 + 0.5 + T/4 = 1.929 s. The throttle is released at steer start.
* ``iso3888-1``: severe double lane change, ISO 3888-1 cone lanes, driver-followed.
* ``dlc-000``: the double lane change of seed 000 Fig. 7 (B1 = B2 = 3.5 m,
  S1 = 60 m, S2 = 40 m, S3 = 60 m), driver-followed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .errors import ManeuverError
from .params import G, VehicleParams
from .paths import DriverModel, Path, path_from_function

MANEUVERS = ("sine-lane-change", "step-steer", "ramp-steer", "constant-radius", "sine-with-dwell",
             "iso3888-1", "dlc-000")


@dataclass(frozen=True)
class Maneuver:
    """One manoeuvre: speed, duration, and an open-loop steer or a path to follow."""

    name: str
    speed: float
    duration: float
    steer: Callable[[np.ndarray], np.ndarray] | None = None
    path: Path | None = None
    coast_from: float | None = None
    """Time [s] from which the speed hold is released (None: hold throughout)."""
    events: dict = field(default_factory=dict)
    cones: np.ndarray | None = None
    """Cone positions (x, y) [m], one row per cone, where the manoeuvre has them."""
    driver: DriverModel | None = None
    """How the path is driven (a :class:`plants.paths.DriverModel`); None: :class:`plants.paths.PathDriver`."""
    speed_profile: Callable[[np.ndarray], np.ndarray] | None = None
    """The speed demand [m/s] over time (None: ``speed`` throughout); the run starts at ``speed``."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.speed) and self.speed >= 0.0):
            raise ManeuverError(f"{self.name}: speed must be >= 0 m/s, got {self.speed!r}")
        if not (np.isfinite(self.duration) and self.duration > 0.0):
            raise ManeuverError(f"{self.name}: duration must be > 0 s, got {self.duration!r}")
        if (self.steer is None) == (self.path is None):
            raise ManeuverError(f"{self.name}: give exactly one of an open-loop steer or a path")

    @property
    def open_loop(self) -> bool:
        return self.steer is not None

    def speed_ref(self, t: np.ndarray) -> np.ndarray:
        """The speed demand [m/s] at times ``t``."""
        t = np.asarray(t, float)
        if self.speed_profile is None:
            return np.full_like(t, float(self.speed))
        return np.asarray(self.speed_profile(t), float) * np.ones_like(t)

    def path_driver(self, params: VehicleParams, dt: float):
        """The driver that follows ``path`` for a car of ``params``, stepped every ``dt`` [s]."""
        from .paths import PathDriver
        if self.path is None:
            raise ManeuverError(f"{self.name}: an open-loop manoeuvre has no path to follow")
        return PathDriver(self.path, params) if self.driver is None else self.driver.make(self.path, params, dt)

    def drive_on(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, float)
        if self.coast_from is None:
            return np.ones_like(t)
        return (t < self.coast_from).astype(float)


def _smoothstep(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def sine_lane_change(speed: float, amplitude: float, *, start: float = 3.0, period: float = 4.0,
                     duration: float = 10.0) -> Maneuver:
    """One full period of ``amplitude * sin(2 pi (t - start) / period)`` (seed 003 Fig. 6)."""
    def steer(t):
        t = np.asarray(t, float)
        ph = (t - start) / period
        return np.where((ph >= 0) & (ph <= 1), amplitude * np.sin(2 * np.pi * ph), 0.0)
    return Maneuver("sine-lane-change", speed, duration, steer=steer,
                    events={"steer_start": start, "steer_end": start + period})


def step_steer(speed: float, amplitude: float, *, start: float = 1.0, rise: float = 0.15,
               duration: float = 6.0) -> Maneuver:
    """Steer ramps linearly from 0 to ``amplitude`` in ``rise`` s at ``start``, then holds."""
    def steer(t):
        return amplitude * np.clip((np.asarray(t, float) - start) / rise, 0.0, 1.0)
    return Maneuver("step-steer", speed, duration, steer=steer, events={"steer_start": start})


def ramp_steer(speed: float, rate: float, *, start: float = 1.0, duration: float = 11.0,
               limit: float | None = None) -> Maneuver:
    """Steer rising at ``rate`` rad/s from ``start`` (optionally capped at ``limit``)."""
    def steer(t):
        d = rate * np.clip(np.asarray(t, float) - start, 0.0, None)
        return d if limit is None else np.clip(d, -abs(limit), abs(limit))
    return Maneuver("ramp-steer", speed, duration, steer=steer, events={"steer_start": start})


def sine_with_dwell(speed: float, amplitude: float, *, frequency: float = 0.7, dwell: float = 0.5,
                    start: float = 1.0, after: float = 3.0) -> Maneuver:
    """FMVSS 126 sine with dwell; positive ``amplitude`` steers left first."""
    T = 1.0 / frequency
    t_peak2 = 0.75 * T
    t_end = t_peak2 + dwell + 0.25 * T

    def steer(t):
        tau = np.asarray(t, float) - start
        w = 2 * np.pi * frequency
        out = np.where(tau < t_peak2, amplitude * np.sin(w * tau), -amplitude)
        out = np.where(tau >= t_peak2 + dwell, amplitude * np.sin(w * (tau - dwell)), out)
        return np.where((tau < 0) | (tau > t_end), 0.0, out)

    return Maneuver("sine-with-dwell", speed, start + t_end + after, steer=steer, coast_from=start,
                    events={"steer_start": start, "first_peak": start + 0.25 * T,
                            "second_peak": start + t_peak2, "dwell_end": start + t_peak2 + dwell,
                            "steer_end": start + t_end})


def vehicle_width(p: VehicleParams) -> float:
    """The car's overall width [m] for cone lanes and cone hits: the file's ``width``, else the wider
    track plus 0.25 m."""
    return p.width if p.width is not None else max(p.track_front or 0.0, p.track_rear or 0.0) + 0.25


def steer_for_lateral_acceleration(p: VehicleParams, speed: float, ay: float) -> float:
    """Road-wheel steer [rad] giving lateral acceleration ``ay`` in steady state (linear bicycle).

    ``delta = L (1 + G v^2) ay / v^2``; an estimate of FMVSS 126's ``A`` (the regulation
    measures it in a slowly increasing steer on the real car).
    """
    if speed <= 0:
        raise ManeuverError(f"speed must be > 0 m/s, got {speed!r}")
    return p.wheelbase * (1.0 + p.stability_factor * speed**2) * ay / speed**2


def constant_radius(speed: float, radius: float = 40.0, *, laps: float = 1.25, lead_in: float = 20.0) -> Maneuver:
    """Follow a circle of ``radius`` m (left turn) after a straight lead-in."""
    if radius <= 0:
        raise ManeuverError(f"constant-radius: radius must be > 0 m, got {radius!r}")
    xs = np.arange(-lead_in, 0.0, 0.25)
    ang = np.arange(0.0, 2 * np.pi * laps, 0.25 / radius)
    path = Path(np.concatenate([xs, radius * np.sin(ang)]),
                np.concatenate([np.zeros_like(xs), radius * (1.0 - np.cos(ang))]))
    duration = max((path.length - lead_in) / max(speed, 0.5), 1.0)
    return Maneuver("constant-radius", speed, duration, path=path, events={"radius": radius})


def two_half_turns(speed: float, radius: float = 60.0, straight: float = 150.0, *,
                   lead_in: float = 50.0) -> Maneuver:
    """Seed 001's test track: two 180-degree constant-radius turns (left) joined by straights, driver-followed.

    A lead-in straight, a half circle of ``radius``, a straight of ``straight`` m back the
    other way, the second half circle, and the first ``lead_in`` m of straight again.
    """
    if radius <= 0 or straight <= 0 or lead_in <= 0:
        raise ManeuverError(f"two-half-turns: radius, straight and lead-in must be > 0 m, got {radius!r}, "
                            f"{straight!r}, {lead_in!r}")
    ds = 0.25
    a = np.arange(0.0, np.pi, ds / radius)
    xs = [np.arange(-lead_in, 0.0, ds), radius * np.sin(a), -np.arange(0.0, straight, ds),
          -straight - radius * np.sin(a), -straight + np.arange(0.0, straight + lead_in, ds)]
    ys = [np.zeros(int(np.ceil(lead_in / ds))), radius * (1.0 - np.cos(a)), np.full(int(np.ceil(straight / ds)),
                                                                                     2 * radius),
          radius * (1.0 + np.cos(a)), np.zeros(int(np.ceil((straight + lead_in) / ds)))]
    path = Path(np.concatenate(xs), np.concatenate(ys))
    duration = (2 * np.pi * radius + 2 * straight + lead_in) / max(speed, 0.5)
    return Maneuver("two-half-turns", speed, duration, path=path, events={"radius": radius})


def _blend(x, x0, length, y0, y1):
    return y0 + (y1 - y0) * 0.5 * (1.0 - np.cos(np.pi * np.clip((x - x0) / length, 0.0, 1.0)))


def iso3888_1_lanes(vehicle_width: float) -> dict:
    """ISO 3888-1 lane geometry for a car of ``vehicle_width`` m.

    Sections 1-5 are 15, 30, 25, 25, 15 m long; lanes 1, 3 and 5 are
    ``1.1 w + 0.25``, ``1.2 w + 0.25`` and ``1.3 w + 0.25`` wide. Lane 1 is centred
    on y = 0; lane 3 is offset 3.5 m to the left, measured between the right-hand
    boundaries of lanes 1 and 3; lane 5 shares lane 1's right-hand boundary.
    Returns section start/end x and each lane's (right, left) boundary y.
    """
    w = vehicle_width
    widths = (1.1 * w + 0.25, 1.2 * w + 0.25, 1.3 * w + 0.25)
    right1 = -widths[0] / 2
    ends = np.cumsum([15.0, 30.0, 25.0, 25.0, 15.0])
    return {
        "sections": tuple(zip(np.concatenate([[0.0], ends[:-1]]), ends)),
        "lane1": (right1, right1 + widths[0]),
        "lane3": (right1 + 3.5, right1 + 3.5 + widths[1]),
        "lane5": (right1, right1 + widths[2]),
        "widths": widths,
    }


def iso3888_1_cones(vehicle_width: float) -> np.ndarray:
    """Cone positions (x, y): the lane boundaries of sections 1, 3 and 5 at both ends and the middle."""
    return lane_cones(iso3888_1_lanes(vehicle_width))


def lane_line(g: dict, lead_in: float, run_out: float) -> Path:
    """The planned line through a lane geometry's (:func:`iso3888_1_lanes`, :func:`iso3888_2_lanes`)
    lane centres, with cosine transitions over sections 2 and 4, from ``lead_in`` m before the entry to
    ``run_out`` m after the exit."""
    c1, c3, c5 = (0.5 * sum(g[k]) for k in ("lane1", "lane3", "lane5"))
    _, (s2, e2), _, (s4, e4), _ = g["sections"]

    def y_of_x(x):
        y = _blend(x, s2, e2 - s2, c1, c3)
        return np.where(x >= s4, _blend(x, s4, e4 - s4, c3, c5), y)

    return path_from_function(y_of_x, -lead_in, g["sections"][-1][1] + run_out)


def iso3888_1(speed: float, vehicle_width: float, *, lead_in: float = 30.0, run_out: float = 40.0) -> Maneuver:
    """ISO 3888-1 double lane change, driver follows the lane centres (cosine transitions)."""
    path = lane_line(iso3888_1_lanes(vehicle_width), lead_in, run_out)
    duration = (path.length - 10.0) / max(speed, 0.5)
    return Maneuver("iso3888-1", speed, duration, path=path, cones=iso3888_1_cones(vehicle_width),
                    events={"lane_offset": 3.5})


def iso3888_2_lanes(vehicle_width: float) -> dict:
    """ISO 3888-2 (obstacle avoidance) lane geometry for a car of ``vehicle_width`` m.

    Sections 1-5 are 12, 13.5, 11, 12.5 and 12 m long; lanes 1, 3 and 5 are ``1.1 w + 0.25``,
    ``w + 1`` and ``1.3 w + 0.25`` (at least 3 m) wide. Lane 1 is centred on y = 0; lane 3 lies
    to the left, its right-hand boundary 1 m left of lane 1's left-hand boundary; lane 5 shares lane
    1's right-hand boundary (evstab's reading of the standard's figure, as in ISO 3888-1).
    Returns section start/end x and each lane's (right, left) boundary y."""
    w = vehicle_width
    widths = (1.1 * w + 0.25, w + 1.0, max(1.3 * w + 0.25, 3.0))
    right1 = -widths[0] / 2
    ends = np.cumsum([12.0, 13.5, 11.0, 12.5, 12.0])
    right3 = right1 + widths[0] + 1.0
    return {"sections": tuple(zip(np.concatenate([[0.0], ends[:-1]]), ends)),
            "lane1": (right1, right1 + widths[0]), "lane3": (right3, right3 + widths[1]),
            "lane5": (right1, right1 + widths[2]), "widths": widths}


def lane_cones(g: dict) -> np.ndarray:
    """Cone positions (x, y) of a lane geometry (:func:`iso3888_1_lanes`, :func:`iso3888_2_lanes`): the
    boundaries of sections 1, 3 and 5 at both ends and the middle."""
    cones = []
    for sec, lane in ((0, "lane1"), (2, "lane3"), (4, "lane5")):
        x0, x1 = g["sections"][sec]
        for xc in (x0, 0.5 * (x0 + x1), x1):
            for yc in g[lane]:
                cones.append((xc, yc))
    return np.array(cones)


def iso3888_2(speed: float, vehicle_width: float, *, driver=None, lead_in: float = 40.0,
              run_out: float = 40.0) -> Maneuver:
    """ISO 3888-2 obstacle avoidance entered at ``speed``: the driver releases the accelerator at the
    entry (x = 0) and steers along a planned line through the lane centres, with cosine transitions
    over sections 2 and 4 (``driver``: a :class:`plants.paths.DriverModel`, default a human's delay
    and lag)."""
    from .paths import DriverModel
    g = iso3888_2_lanes(vehicle_width)
    path = lane_line(g, lead_in, run_out)
    duration, entry = (path.length - 10.0) / max(speed, 0.5), lead_in / max(speed, 0.5)
    return Maneuver("iso3888-2", speed, duration, path=path, cones=lane_cones(g), coast_from=entry,
                    driver=DriverModel() if driver is None else driver, events={"entry": entry})


def slalom(speed: float, vehicle_width: float, *, spacing: float = 18.0, cones: int = 7, clearance: float = 0.2,
           driver=None, lead_in: float = 40.0, run_out: float = 40.0) -> Maneuver:
    """A slalom through ``cones`` cones ``spacing`` m apart on y = 0: the planned line is a cosine
    ``y = A cos(pi x / spacing)`` that passes each cone on alternate sides with the car's side
    ``clearance`` m from it (``A = w / 2 + clearance``), entered straight, at constant ``speed``; its
    lateral acceleration peaks at ``A (pi v / spacing)^2``."""
    from .paths import DriverModel
    amp = 0.5 * vehicle_width + clearance
    x_end = spacing * (cones - 1)

    def y_of_x(x):
        return -amp * np.cos(np.pi * x / spacing) * _smooth_gate(x, spacing, x_end)

    path = path_from_function(y_of_x, -lead_in, x_end + run_out)
    cone_xy = np.column_stack([spacing * np.arange(cones), np.zeros(cones)])
    return Maneuver("slalom", speed, (path.length - 10.0) / max(speed, 0.5), path=path, cones=cone_xy,
                    driver=DriverModel() if driver is None else driver,
                    events={"spacing": spacing, "amplitude": amp})


def _smooth_gate(x, spacing, x_end):
    """1 over the cones, rising and falling over the half spacing before the first and after the last,
    0 beyond."""
    up = 0.5 * (1.0 - np.cos(np.pi * np.clip((x + 0.5 * spacing) / (0.5 * spacing), 0.0, 1.0)))
    down = 0.5 * (1.0 - np.cos(np.pi * np.clip((x_end + 0.5 * spacing - x) / (0.5 * spacing), 0.0, 1.0)))
    return up * down


def random_steer(speed: float, p: VehicleParams, *, ay_max: float = 4.0, seed: int = 0, duration: float = 30.0,
                 bandwidth: float = 0.5) -> Maneuver:
    """Smooth random steering: band-limited noise (up to ``bandwidth`` Hz; seeded) scaled so that the
    nominal linear car's steady-state lateral acceleration stays within ``ay_max`` [m/s^2]."""
    rng = np.random.default_rng(seed)
    dt = 0.01
    tt = np.arange(0.0, duration + dt, dt)
    spec = np.fft.rfft(rng.standard_normal(len(tt)))
    f = np.fft.rfftfreq(len(tt), dt)
    spec[f > bandwidth] = 0.0
    x = np.fft.irfft(spec, len(tt)) * _smoothstep(tt / 2.0) * _smoothstep((duration - tt) / 2.0)
    x *= steer_for_lateral_acceleration(p, speed, ay_max) / np.max(np.abs(x))

    def steer(t):
        return np.interp(np.asarray(t, float), tt, x)
    return Maneuver("random-steer", speed, duration, steer=steer, events={"ay_max": ay_max, "seed": seed})


def dlc_000(speed: float, *, b1: float = 3.5, b2: float = 3.5, s1: float = 60.0, s2: float = 40.0,
            s3: float = 60.0, lead_in: float = 30.0, run_out: float = 40.0) -> Maneuver:
    """Seed 000 double lane change: change by ``b2`` over ``s1``, hold ``s2``, return over ``s3``.

    Seed 000 gives B1 = B2 = 3.5 m and S1, S2, S3 = 60, 40, 60 m without defining
    them further; evstab reads B1 as the lane width and B2 as the lateral offset
    of the adjacent lane, S1/S3 as the lengths of the two transitions and S2 as the
    length driven in the adjacent lane. Transitions are cosine-shaped.
    """
    def y_of_x(x):
        y = _blend(x, 0.0, s1, 0.0, b2)
        return np.where(x >= s1 + s2, _blend(x, s1 + s2, s3, b2, 0.0), y)

    path = path_from_function(y_of_x, -lead_in, s1 + s2 + s3 + run_out)
    duration = (path.length - 10.0) / max(speed, 0.5)
    return Maneuver("dlc-000", speed, duration, path=path, events={"lane_width": b1, "offset": b2})


def make_maneuver(name: str, p: VehicleParams, speed: float, amplitude: float | None = None) -> Maneuver:
    """Build a manoeuvre by name with the CLI's conventions.

    Parameters
    ----------
    name : str
        One of :data:`MANEUVERS` (``step-steer``, ``sine-lane-change``, ``ramp-steer``,
        ``sine-with-dwell``, ``constant-radius``, ``iso3888-1``, ``dlc-000``).
    p : VehicleParams
        The vehicle (its linear model sets default amplitudes; its width the ISO 3888-1 lanes).
    speed : float
        Speed [m/s] the manoeuvre is driven at.
    amplitude : float, optional
        Road-wheel angle [rad] (see below); None: the default.

    Returns
    -------
    Maneuver
        The steer profile (or path for the path follower), speed and duration.

    ``amplitude`` [rad] is the road-wheel amplitude (step, sine, sine-with-dwell),
    the final angle of the ramp (reached 10 s after its start), or ignored for the
    path-following manoeuvres. Defaults: 2 deg (step), 3 deg (sine lane change),
    5 A (sine with dwell, A from :func:`steer_for_lateral_acceleration` at 0.3 g),
    A over 10 s (ramp).

    Examples
    --------
    >>> from evstab.plants import load_vehicle
    >>> from evstab.plants.maneuvers import make_maneuver
    >>> m = make_maneuver("step-steer", load_vehicle("compact-ev"), 60 / 3.6)
    >>> m.name, m.duration, round(m.speed * 3.6)
    ('step-steer', 6.0, 60)
    """
    deg = np.pi / 180.0
    if name == "sine-lane-change":
        return sine_lane_change(speed, 3 * deg if amplitude is None else amplitude)
    if name == "step-steer":
        return step_steer(speed, 2 * deg if amplitude is None else amplitude)
    if name == "ramp-steer":
        final = 2 * steer_for_lateral_acceleration(p, max(speed, 1.0), 0.3 * G) if amplitude is None else amplitude
        return ramp_steer(speed, final / 10.0)
    if name == "sine-with-dwell":
        a = 5 * steer_for_lateral_acceleration(p, max(speed, 1.0), 0.3 * G) if amplitude is None else amplitude
        return sine_with_dwell(speed, a)
    if name == "constant-radius":
        return constant_radius(speed)
    if name == "iso3888-1":
        return iso3888_1(speed, vehicle_width(p))
    if name == "dlc-000":
        return dlc_000(speed)
    raise ManeuverError(f"unknown manoeuvre '{name}'; known: {', '.join(MANEUVERS)}")
