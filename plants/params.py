"""Vehicle parameter sets: a frozen, validated dataclass and its TOML loader.

The TOML format is described in docs/formats.md::

    [meta]
    name = "..."
    source = "where the numbers come from"

    [vehicle]
    mass = 1500.0   # kg
    ...

Cornering stiffness is per tire [N/rad]; an axle has twice that (the papers'
``2 C_f`` terms).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path

from .errors import ParameterError

G = 9.80665
"""Standard gravity [m/s^2]."""

WHEELBASE_RANGE = (1.0, 6.0)
"""Wheelbase [m] of a road vehicle (a micro car to a long van)."""
MASS_MIN = 50.0
"""Smallest total mass [kg] of a road vehicle."""
DYNAMIC_INDEX_RANGE = (0.3, 3.0)
"""Range of the dynamic index I_z / (m l_f l_r) (0.8-1.2 for road cars; the bundled vehicles 0.91-1.10)."""
WHEEL_RADIUS_RANGE = (0.15, 0.6)
"""Rolling radius [m] of a road vehicle's wheel."""
STEERING_RATIO_RANGE = (5.0, 30.0)
"""Hand-wheel to road-wheel ratio of a road vehicle."""

_REQUIRED = (
    "mass",
    "yaw_inertia",
    "lf",
    "lr",
    "cornering_stiffness_front",
    "cornering_stiffness_rear",
)


def _field(doc: str, lo: float | None = None, hi: float | None = None, *, default=dataclasses.MISSING,
           strict_lo: bool = True):
    meta = {"doc": doc, "lo": lo, "hi": hi, "strict_lo": strict_lo}
    if default is dataclasses.MISSING:
        return field(metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True, kw_only=True)
class VehicleParams:
    """Physical parameters of one vehicle, SI units, validated on construction.

    Only the six planar-bicycle quantities are required; the roll, two-track and
    sensor-placement models each name the optional fields they need and raise a
    :class:`ParameterError` naming any that are missing (:meth:`require`).
    Variants are made with :func:`dataclasses.replace`, which re-validates.
    """

    name: str = _field("name of the parameter set", default="unnamed")
    source: str = _field("where the numbers come from", default="")

    mass: float = _field("total vehicle mass M [kg]", 0.0, 1e5)
    yaw_inertia: float = _field("yaw moment of inertia I_z about the CG [kg m^2]", 0.0, 1e6)
    lf: float = _field("CG to front axle l_f [m]", 0.0, 10.0, strict_lo=False)
    lr: float = _field("CG to rear axle l_r [m]", 0.0, 10.0, strict_lo=False)
    cornering_stiffness_front: float = _field("cornering stiffness of ONE front tire C_f [N/rad]", 0.0, 1e6)
    cornering_stiffness_rear: float = _field("cornering stiffness of ONE rear tire C_r [N/rad]", 0.0, 1e6)

    # Optional: the designer's nominal model when it differs from the truth (seeds 003/004).
    nominal_cornering_stiffness_front: float | None = _field(
        "cornering stiffness per front tire assumed by a nominal design model [N/rad]", 0.0, 1e6, default=None)
    nominal_cornering_stiffness_rear: float | None = _field(
        "cornering stiffness per rear tire assumed by a nominal design model [N/rad]", 0.0, 1e6, default=None)

    # Optional: roll model (seed 004 eq. 1-9, seed 000 eq. 11-12).
    sprung_mass: float | None = _field("sprung mass M_s [kg]", 0.0, 1e5, default=None)
    roll_inertia: float | None = _field("roll moment of inertia of the sprung mass about the roll axis I_x [kg m^2]",
                                        0.0, 1e6, default=None)
    roll_damping: float | None = _field("total suspension roll damping C_x [N m s/rad]", 0.0, 1e7,
                                        default=None, strict_lo=False)
    roll_stiffness: float | None = _field("total suspension roll stiffness K_x [N m/rad]", 0.0, 1e8, default=None)
    roll_stiffness_front_share: float | None = _field(
        "front axle share of the roll stiffness (load-transfer split) [-]", 0.0, 1.0, default=None)
    roll_arm: float | None = _field("sprung-mass CG height above the roll axis h_s [m]", 0.0, 5.0,
                                    default=None, strict_lo=False)
    cg_height: float | None = _field("CG height above ground h [m]", 0.0, 5.0, default=None)

    # Optional: two-track geometry, wheels and tires.
    track_front: float | None = _field("front track width t_f [m]", 0.0, 5.0, default=None)
    track_rear: float | None = _field("rear track width t_r [m]", 0.0, 5.0, default=None)
    width: float | None = _field("overall vehicle width (cone-lane sizing) [m]", 0.0, 5.0, default=None)
    wheel_radius: float | None = _field("effective rolling radius R_w [m]", 0.0, 3.0, default=None)
    wheel_inertia: float | None = _field("spin inertia of one wheel incl. in-wheel motor rotor I_w [kg m^2]",
                                         0.0, 100.0, default=None)
    longitudinal_stiffness: float | None = _field("longitudinal slip stiffness of ONE tire C_kappa [N per unit slip]",
                                                  0.0, 1e7, default=None)
    tire_shape_factor: float = _field("Magic Formula shape factor C of the combined-slip tire [-]", 1.0, 2.0,
                                      default=1.3)
    tire_curvature_factor: float = _field("Magic Formula curvature factor E of the combined-slip tire [-]",
                                          -5.0, 1.0, default=-2.0, strict_lo=False)
    mu: float = _field("nominal tire-road friction coefficient [-]", 0.0, 2.0, default=1.0)

    # Optional: resistances (zero = neglected, as seed 000 assumption 3).
    frontal_area: float = _field("frontal area A [m^2]", 0.0, 20.0, default=0.0, strict_lo=False)
    drag_coefficient: float = _field("aerodynamic drag coefficient C_d [-]", 0.0, 3.0, default=0.0, strict_lo=False)
    rolling_resistance: float = _field("rolling resistance coefficient f_r [-]", 0.0, 0.1, default=0.0,
                                       strict_lo=False)

    # Optional: steering and actuators.
    steering_ratio: float | None = _field("hand-wheel to road-wheel steering ratio [-]", 1.0, 100.0, default=None)
    steer_authority: float | None = _field(
        "largest steer correction the active front steering may add to the driver's road-wheel angle [rad]",
        0.0, 1.0, default=None, strict_lo=False)
    steer_authority_rate: float | None = _field("largest rate of that steer correction [rad/s]", 0.0, 100.0,
                                                default=None)
    max_motor_torque: float | None = _field("peak torque of one rear in-wheel motor at the wheel [N m]",
                                            0.0, 1e5, default=None)

    # Optional: friction brakes at every wheel (hydraulic; controllers.brakes).
    brake_gain_front: float | None = _field("brake torque per unit pressure at ONE front wheel [N m/Pa]", 0.0, 1e-2,
                                            default=None)
    brake_gain_rear: float | None = _field("brake torque per unit pressure at ONE rear wheel [N m/Pa]", 0.0, 1e-2,
                                           default=None)
    brake_pressure_max: float | None = _field("largest wheel-brake pressure the hydraulic unit makes [Pa]", 0.0, 1e8,
                                              default=None)
    brake_tau: float | None = _field("time constant of a wheel brake's pressure [s]", 0.0, 1.0, default=None)
    brake_build_rate: float | None = _field("fastest pressure build-up at one wheel brake [Pa/s]", 0.0, 1e10,
                                            default=None)
    brake_release_rate: float | None = _field("fastest pressure release at one wheel brake [Pa/s]", 0.0, 1e10,
                                              default=None)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("name", "source"):
                if not isinstance(value, str):
                    raise ParameterError(f"{self.name}: field '{f.name}' must be text, got {value!r}")
                continue
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ParameterError(
                    f"{self.name}: field '{f.name}' ({f.metadata['doc']}) must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ParameterError(f"{self.name}: field '{f.name}' must be finite, got {value!r}")
            lo, hi = f.metadata["lo"], f.metadata["hi"]
            strict = f.metadata["strict_lo"]
            too_low = lo is not None and (value <= lo if strict else value < lo)
            too_high = hi is not None and value > hi
            if too_low or too_high:
                bracket = "(" if strict else "["
                raise ParameterError(
                    f"{self.name}: field '{f.name}' ({f.metadata['doc']}) = {value!r} is outside "
                    f"the allowed range {bracket}{lo}, {hi}]")
        self._check_physics()

    def _check_physics(self) -> None:
        """Relations between fields that physics (or any road car) fixes; each message names the
        fields, their values and the bound."""
        n = self.name
        L = self.lf + self.lr
        if not WHEELBASE_RANGE[0] <= L <= WHEELBASE_RANGE[1]:
            raise ParameterError(
                f"{n}: wheelbase lf + lr = {self.lf!r} + {self.lr!r} = {L:.4g} m is outside "
                f"[{WHEELBASE_RANGE[0]}, {WHEELBASE_RANGE[1]}] m (lf and lr are in metres)")
        if self.mass < MASS_MIN:
            raise ParameterError(f"{n}: field 'mass' = {self.mass!r} kg is below {MASS_MIN:g} kg (the total vehicle "
                                 "mass, in kg)")
        index = self.yaw_inertia / (self.mass * self.lf * self.lr) if self.lf > 0 and self.lr > 0 else None
        if index is not None and not DYNAMIC_INDEX_RANGE[0] <= index <= DYNAMIC_INDEX_RANGE[1]:
            raise ParameterError(
                f"{n}: field 'yaw_inertia' = {self.yaw_inertia!r} kg m^2 gives a dynamic index I_z / (m l_f l_r) "
                f"= {index:.3g}, outside [{DYNAMIC_INDEX_RANGE[0]}, {DYNAMIC_INDEX_RANGE[1]}] (road cars: 0.8-1.2; "
                "the yaw inertia is in kg m^2 about the CG)")
        if self.sprung_mass is not None and self.sprung_mass > self.mass:
            raise ParameterError(
                f"{n}: field 'sprung_mass' = {self.sprung_mass!r} kg exceeds 'mass' = {self.mass!r} kg "
                "(the sprung mass is part of the total)")
        if self.roll_inertia is not None and self.sprung_mass is not None and self.roll_arm is not None:
            least = self.sprung_mass * self.roll_arm ** 2
            if self.roll_inertia < least:
                raise ParameterError(
                    f"{n}: field 'roll_inertia' = {self.roll_inertia!r} kg m^2 is below sprung_mass * roll_arm^2 "
                    f"= {self.sprung_mass!r} * {self.roll_arm!r}^2 = {least:.4g} kg m^2: the inertia about the "
                    "roll axis is the sprung mass's own plus m_s h^2 (parallel-axis theorem); a value below "
                    "that is the inertia about the sprung mass's CG")
        if self.roll_stiffness is not None and self.sprung_mass is not None and self.roll_arm is not None:
            gravity = self.sprung_mass * G * self.roll_arm
            if not self.roll_stiffness > gravity:
                raise ParameterError(
                    f"{n}: field 'roll_stiffness' = {self.roll_stiffness!r} N m/rad does not exceed the rolled body's "
                    f"gravity moment sprung_mass * g * roll_arm = {gravity:.4g} N m/rad: the suspension cannot hold "
                    "the body up (roll_stiffness is the suspension's own, without the gravity moment)")
        if self.width is not None:
            for k in ("track_front", "track_rear"):
                t = getattr(self, k)
                if t is not None and t > self.width:
                    raise ParameterError(
                        f"{n}: field '{k}' = {t!r} m exceeds the overall 'width' = {self.width!r} m")
        if self.wheel_radius is not None and not WHEEL_RADIUS_RANGE[0] <= self.wheel_radius <= WHEEL_RADIUS_RANGE[1]:
            raise ParameterError(
                f"{n}: field 'wheel_radius' = {self.wheel_radius!r} m is outside "
                f"[{WHEEL_RADIUS_RANGE[0]}, {WHEEL_RADIUS_RANGE[1]}] m (a road car's rolling radius, in metres)")
        if self.steering_ratio is not None and not STEERING_RATIO_RANGE[0] <= self.steering_ratio <= STEERING_RATIO_RANGE[1]:
            raise ParameterError(
                f"{n}: field 'steering_ratio' = {self.steering_ratio!r} is outside "
                f"[{STEERING_RATIO_RANGE[0]}, {STEERING_RATIO_RANGE[1]}] (hand-wheel angle / road-wheel angle)")

    # ----------------------------------------------------------------- derived
    @property
    def wheelbase(self) -> float:
        """Wheelbase L = l_f + l_r [m]."""
        return self.lf + self.lr

    @property
    def static_axle_load_front(self) -> float:
        """Static vertical load on the front axle M g l_r / L [N]."""
        return self.mass * G * self.lr / self.wheelbase

    @property
    def static_axle_load_rear(self) -> float:
        """Static vertical load on the rear axle M g l_f / L [N]."""
        return self.mass * G * self.lf / self.wheelbase

    @property
    def stability_factor(self) -> float:
        """Stability factor G of seed 003 eq. 24 [s^2/m^2].

        ``G = M / (2 L^2) * (C_r l_r - C_f l_f) / (C_f C_r)`` with per-tire stiffness;
        the steady-state yaw-rate gain is ``v / (L (1 + G v^2))``.
        """
        cf, cr = self.cornering_stiffness_front, self.cornering_stiffness_rear
        return self.mass / (2.0 * self.wheelbase**2) * (cr * self.lr - cf * self.lf) / (cf * cr)

    @property
    def understeer_gradient(self) -> float:
        """Understeer gradient K_us [rad per m/s^2] (positive = understeer).

        ``K_us = M/L * (l_r/(2 C_f) - l_f/(2 C_r)) = G L``; steady-state steer is
        ``delta = L/R + K_us a_y``.
        """
        return self.stability_factor * self.wheelbase

    @property
    def characteristic_speed(self) -> float:
        """Speed of maximum yaw-rate gain sqrt(1/G) for an understeering car [m/s]; inf otherwise."""
        g = self.stability_factor
        return math.sqrt(1.0 / g) if g > 0.0 else math.inf

    @property
    def critical_speed(self) -> float:
        """Speed above which an oversteering car is unstable sqrt(-1/G) [m/s]; inf otherwise."""
        g = self.stability_factor
        return math.sqrt(-1.0 / g) if g < 0.0 else math.inf

    @property
    def roll_gradient(self) -> float | None:
        """Steady body roll per lateral acceleration [rad per m/s^2], or None without the roll data.

        The sprung mass's roll moment balances the suspension's, with the gravity moment of the rolled
        body (``roll_stiffness`` is the suspension's, as in the two-track model):
        ``K phi = m_s h_s a_y + m_s g h_s phi``, so ``phi / a_y = m_s h_s / (K - m_s g h_s)``;
        ``K > m_s g h_s`` is checked when the file is read."""
        if self.sprung_mass is None or self.roll_arm is None or self.roll_stiffness is None:
            return None
        msh = self.sprung_mass * self.roll_arm
        return msh / (self.roll_stiffness - msh * G)

    @property
    def roll_reading_factor(self) -> float:
        """The car's lateral acceleration in the road plane per lateral accelerometer reading in steady
        cornering [-]: the body rolls ``phi = k a_y`` (``k`` :attr:`roll_gradient`) and the accelerometer
        reads ``a_y + g phi``, so ``1 / (1 + g k)``; 1 without the roll data."""
        k = self.roll_gradient
        return 1.0 / (1.0 + G * (0.0 if k is None else k))

    @property
    def rollover_threshold(self) -> float | None:
        """Quasi-static rollover threshold [m/s^2], or None without the CG height and the tracks.

        The steady lateral acceleration at which the inner wheels lift: the overturning moment about the
        outer contact line, ``m a_y h`` plus the rolled sprung mass's shift ``m_s g h_s phi``, equals the
        weight's ``m g t / 2`` (``t`` the mean track), with ``phi`` from :attr:`roll_gradient`:
        ``a_y = m g t / (2 (m h + m_s g h_s phi / a_y))`` (T. D. Gillespie, *Fundamentals of Vehicle
        Dynamics*, SAE, 1992, ch. 9, the suspended vehicle). Without the roll data it is the rigid car's
        static stability factor ``g t / (2 h)``; the body's roll lowers it, by 7-13 % on the bundled cars."""
        if self.cg_height is None or self.track_front is None or self.track_rear is None or not self.cg_height > 0:
            return None
        t = 0.5 * (self.track_front + self.track_rear)
        k = self.roll_gradient
        shift = 0.0
        if k is not None and self.sprung_mass is not None and self.roll_arm is not None:
            shift = self.sprung_mass * G * self.roll_arm * k
        return self.mass * G * t / (2.0 * (self.mass * self.cg_height + shift))

    # ---------------------------------------------------------------- helpers
    def require(self, *names: str, model: str = "this model") -> None:
        """Raise :class:`ParameterError` naming every field in ``names`` that is unset."""
        missing = [n for n in names if getattr(self, n) is None]
        if missing:
            raise ParameterError(
                f"{self.name}: {model} needs vehicle parameter(s) {', '.join(missing)}; "
                f"add them to the [vehicle] table")

    def as_nominal(self) -> "VehicleParams":
        """The parameter set a nominal design model assumes (nominal cornering stiffness if given)."""
        cf = self.nominal_cornering_stiffness_front or self.cornering_stiffness_front
        cr = self.nominal_cornering_stiffness_rear or self.cornering_stiffness_rear
        return dataclasses.replace(self, cornering_stiffness_front=cf, cornering_stiffness_rear=cr)

    def to_dict(self) -> dict:
        """All fields as a plain dict (unset optional fields omitted)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    def digest(self) -> str:
        """SHA-256 of the physical values (not name/source): identifies a parameter set in exports."""
        d = {k: v for k, v in self.to_dict().items() if k not in ("name", "source")}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


VEHICLE_KEYS = tuple(f.name for f in fields(VehicleParams) if f.name not in ("name", "source"))


def parse_vehicle_toml(text: str, origin: str) -> VehicleParams:
    """Parse TOML text into :class:`VehicleParams`; errors name ``origin`` and the key."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"{origin}: not valid TOML: {exc}") from None
    unknown_tables = sorted(set(doc) - {"meta", "vehicle"})
    if unknown_tables:
        raise ParameterError(f"{origin}: unknown table(s) {unknown_tables}; expected [meta] and [vehicle]")
    for table in ("meta", "vehicle"):
        if table not in doc:
            raise ParameterError(f"{origin}: missing table [{table}]")
        if not isinstance(doc[table], dict):
            raise ParameterError(f"{origin}: '{table}' must be a table")
    meta, veh = doc["meta"], doc["vehicle"]
    unknown_meta = sorted(set(meta) - {"name", "source", "notes"})
    if unknown_meta:
        raise ParameterError(f"{origin}: unknown key '{unknown_meta[0]}' in [meta]; allowed: name, source, notes")
    for key in ("name", "source"):
        if key not in meta:
            raise ParameterError(f"{origin}: missing key '{key}' in [meta]")
        if not isinstance(meta[key], str):
            raise ParameterError(f"{origin}: key '{key}' in [meta] must be a string")
    unknown = sorted(set(veh) - set(VEHICLE_KEYS))
    if unknown:
        raise ParameterError(
            f"{origin}: unknown key '{unknown[0]}' in [vehicle]; allowed keys: {', '.join(VEHICLE_KEYS)}")
    missing = [k for k in _REQUIRED if k not in veh]
    if missing:
        raise ParameterError(f"{origin}: missing required key '{missing[0]}' in [vehicle]")
    try:
        return VehicleParams(name=meta["name"], source=meta["source"], **veh)
    except ParameterError as exc:
        raise ParameterError(f"{origin}: {exc}") from None


def bundled_vehicles() -> dict[str, str]:
    """The bundled vehicle files.

    Returns
    -------
    dict of str to str
        File name (what :func:`load_vehicle` takes) -> the file's ``[meta] name``.

    Examples
    --------
    >>> from evstab.plants import bundled_vehicles
    >>> sorted(bundled_vehicles())
    ['commonroad-1', 'commonroad-2', 'commonroad-3', 'compact-ev', 'micro-ev', 'sedan-000']
    """
    out = {}
    for entry in sorted(resources.files("evstab.plants").joinpath("data").iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".toml"):
            out[entry.name[:-5]] = tomllib.loads(entry.read_text())["meta"]["name"]
    return out


def load_vehicle(name_or_path: str | Path) -> VehicleParams:
    """Load a bundled vehicle by name or a vehicle TOML file.

    Parameters
    ----------
    name_or_path : str or pathlib.Path
        A bundled name (:func:`bundled_vehicles`: ``compact-ev``, ``micro-ev``, ``sedan-000``,
        ``commonroad-1`` .. ``commonroad-3``) or the path of a TOML file (``docs/formats.md``).

    Returns
    -------
    VehicleParams
        The validated parameters, SI units (kg, m, kg m^2, N/rad per tire, ...).

    Raises
    ------
    ParameterError
        The file is missing, not TOML, lacks a required key, or a value is out of its range or
        against physics; the message names the file, the key, the value and the bound.

    Examples
    --------
    >>> from evstab.plants import load_vehicle
    >>> p = load_vehicle("compact-ev")
    >>> p.mass, round(p.wheelbase, 3), p.cornering_stiffness_front  # kg, m, N/rad per tyre
    (1550.0, 2.6, 52000.0)
    """
    key = str(name_or_path)
    data = resources.files("evstab.plants").joinpath("data")
    if not key.endswith(".toml") and data.joinpath(key + ".toml").is_file():
        return parse_vehicle_toml(data.joinpath(key + ".toml").read_text(), f"bundled vehicle '{key}'")
    path = Path(key)
    if not path.is_file():
        raise ParameterError(
            f"{key}: no such vehicle file and not a bundled vehicle; bundled: {', '.join(bundled_vehicles())}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ParameterError(f"{path}: cannot read as UTF-8 text: {exc}") from None
    return parse_vehicle_toml(text, str(path))


def known(p, *names: str) -> tuple[float, ...]:
    """The values of the optional fields ``names`` of the parameters ``p`` that a plant model needs (floats,
    or a trace's symbols where ``p`` is a :func:`toolkit.kernels.compiled.symbolic_view`). Unchecked here: the
    plant's ``required_params`` are checked once, by :meth:`plants.model.PlantModel.check_params`, not on every
    evaluation of its right-hand side."""
    return tuple(getattr(p, n) for n in names)
