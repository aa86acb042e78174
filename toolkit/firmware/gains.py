"""The self-describing JSON gain set (``evstab_gains.json``) and its loader.

Format ``evstab-gains/2``: everything the firmware's step needs and everything a
reader needs to use it without evstab: control period, GPS model, the signal order
with units and ISO 8855 signs, the state layout and initial value, the estimator's
and controller's settings, every calibration scalar (value, unit, limits, C symbol;
written there alone, not again in the settings: K_beta is in the file once),
the speed-scheduling grid with its interpolation rule, the torque split, the
parameter-set hash, the evstab version and the design's provenance.

:func:`load_gains` rebuilds the :class:`~toolkit.ecu.step.EcuDesign`;
``gains_document(*load_gains(doc))`` is ``doc`` again, number for number (floats are
written with Python's shortest round-trip repr).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

from evstab.controllers.schedule import ROWS, RULE, UNITS, SpeedSchedule
from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants.errors import EvstabError
from evstab.plants.params import VehicleParams

from ..estimation.spec import FilterDesign, NoiseSettings, design_filter
from ..ecu.step import INPUTS, OUTPUTS, EcuDesign

FORMAT = "evstab-gains/2"
READS = ("evstab-gains/1", FORMAT)
"""The formats :func:`load_gains` reads: ``/1`` also wrote each calibration scalar in its section (controller,
estimator noise, torque split), which the calibration list overrides."""
_CTL_SKIP = ("params", "schedule", "method")


class GainSetError(EvstabError, ValueError):
    """A gain-set file is unreadable or a field is missing or wrong."""


def gains_document(d: EcuDesign, provenance: dict, gps: dict) -> dict:
    """The JSON document of ``d``. ``provenance``: the design's (version, revision, command, ...);
    ``gps``: the GPS set-up it was designed for (``rate_hz``, ``latency_s``, ...)."""
    from .csource import symbol_names
    f, c, p = d.filter, d.controller, d.controller.params
    names = symbol_names(d)
    fmin, cmin = d.min_speeds
    lay = d.layout
    cal = d.calibration()
    calibrated = {c.name for c in cal}  # written once, in the calibration list
    return {
        "format": FORMAT,
        "description": "evstab stability-control ECU step: multi-rate Kalman filter (gyro every period, GPS course "
                       "when a fix arrives) and 2-DOF model-following controller (front steer + rear in-wheel-motor "
                       "yaw moment), speed-scheduled by table interpolation.",
        "conventions": "SI units, angles in rad; ISO 8855 axes (x forward, y left, z up); yaw, yaw rate, sideslip, "
                       "steer and course positive counter-clockwise seen from above; steer is the front road-wheel "
                       "angle; course = yaw + sideslip at the antenna, wrapped or continuous; yaw wrapped to (-pi, pi]",
        "evstab_version": provenance.get("evstab_version", "unknown"),
        "vehicle": {"name": p.name, "params_digest": p.digest(), "nominal_params": p.to_dict()},
        "control_period_s": f.dt_nominal,
        "gps": dict(gps, model="single-antenna course over ground; a fix is flagged by gps_valid on the period it "
                               "arrives; fixes with fewer than 4 satellites or below the filter's GPS speed are not "
                               "used; course noise from HDOP and speed when hdop_noise",
                    latency_compensated_s=f.latency, latency_samples=f.latency_samples),
        "signals": {
            "inputs": [{"index": INPUTS.index(s.name), "name": s.name, "unit": s.unit,
                        "c_type": "int" if s.ctype == "int" else "evstab_real", "description": s.doc}
                       for s in INPUTS.signals],
            "outputs": [{"index": OUTPUTS.index(s.name), "name": s.name, "unit": s.unit, "description": s.doc}
                        for s in OUTPUTS.signals],
        },
        "step": "each period: the filter takes the measurements and the yaw moment applied over the last period; "
                "the controller takes the new estimates, the driver's steer and the actuators' limit flags of the "
                "last period; the yaw-moment command is split over the rear motors as +-N_z R_w / t_r, limited to "
                "torque_max",
        "state": {"size": d.n_state, "layout": lay.offsets(),
                  "initial": [float(v) for v in d.initial_state()]},
        "estimator": {
            "method": f.method, "states": list(f.states), "disturbance": f.disturbance, "bias": f.bias,
            "gating": f.gating, "hdop_noise": f.hdop_noise, "standstill_update": f.standstill_update,
            "residual_prediction": f.residual_prediction, "kinematic": bool(f.kinematic), "latency_s": f.latency,
            "antenna_x_m": f.antenna_x,
            "noise": {k.name: float(getattr(f.noise, k.name)) for k in dataclasses.fields(f.noise)
                      if k.name not in calibrated},
        },
        "controller": {k.name: _num(getattr(c, k.name)) for k in dataclasses.fields(c)
                       if k.name not in _CTL_SKIP and k.name not in calibrated},
        "calibration": [{"name": x.name, "symbol": names[x.name], "value": x.value, "unit": x.unit,
                         "lower": x.lower, "upper": x.upper, "owner": x.owner, "description": x.description}
                        for x in cal],
        "schedule": {
            "axis": {"name": "inv_speed", "symbol": names["inv_speed"], "unit": "s/m",
                     "values": list(d.schedule.inv_speed)},
            "speeds_m_per_s": [float(v) for v in d.schedule.speeds],
            "rows": [{"name": r, "symbol": names[r], "unit": UNITS[i], "values": list(d.schedule.table[i])}
                     for i, r in enumerate(ROWS)],
            "interpolation": RULE,
            "evaluated_at": {"filter": f"max(speed, {fmin!r})", "controller": f"max(speed, {cmin!r})"},
            "max_relative_interpolation_error": d.schedule.max_error(p),
        },
        "torque_split": {"track_rear_m": d.track_rear, "wheel_radius_m": d.wheel_radius,
                         "torque_max": "the calibration list's torque_max"},
        "provenance": provenance,
    }


def _num(v):
    """JSON has no infinity: an unlimited bound (``beta_error_max``) is written as null."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v) if math.isfinite(v) else None
    return v


def write_gains(path, doc: dict) -> None:
    from ..logs.drivelog import atomic_write
    atomic_write(path, lambda fh: fh.write(dumps(doc)))


def dumps(doc: dict) -> str:
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def load_gains(path_or_doc) -> tuple[EcuDesign, dict, dict]:
    """``(design, provenance, gps)`` from a gain-set file (or its parsed document).

    Errors name the file and the field.
    """
    where = "gain set"
    if isinstance(path_or_doc, dict):
        doc = path_or_doc
    else:
        where = str(path_or_doc)
        try:
            doc = json.loads(Path(path_or_doc).read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise GainSetError(f"{where}: cannot read a gain set ({e})") from None
    if not isinstance(doc, dict) or doc.get("format") not in READS:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise GainSetError(f"{where}: field 'format' is {got!r}, expected {FORMAT!r}")
    field = "vehicle.nominal_params"
    try:
        params = VehicleParams(**doc["vehicle"]["nominal_params"])
        field = "calibration"
        cal = {c["name"]: c["value"] for c in doc["calibration"]}
        owned = {o: {c["name"]: c["value"] for c in doc["calibration"] if c["owner"] == o} for o in ("controller", "noise")}
        field = "estimator"
        est = doc["estimator"]
        fd = design_filter(est["method"], params, NoiseSettings(**{**est["noise"], **owned["noise"]}),
                           latency=est["latency_s"], antenna_x=est["antenna_x_m"], dt=doc["control_period_s"],
                           nominal=False, control=True, kinematic=bool(est.get("kinematic", False)))
        field = "schedule"
        s = doc["schedule"]
        sched = SpeedSchedule(tuple(float(v) for v in s["axis"]["values"]),
                              tuple(tuple(float(v) for v in r["values"]) for r in s["rows"]))
        if [r["name"] for r in s["rows"]] != list(ROWS):
            raise GainSetError(f"rows must be {', '.join(ROWS)} in that order")
        field = "controller"
        ctl = TwoDofDesign(params, schedule=sched, **{k: (math.inf if v is None else v)
                                                      for k, v in {**doc["controller"], **owned["controller"]}.items()})
        field = "torque_split"
        ts = doc["torque_split"]
        d = EcuDesign(dataclasses.replace(fd, schedule=sched), ctl, float(cal.get("torque_max", 1.0)),
                      float(ts["track_rear_m"]), float(ts["wheel_radius_m"]))
        field = "calibration"
        d = _apply_calibration(d, cal)
        field = "state"
        if doc["state"]["size"] != d.n_state:
            raise GainSetError(f"size {doc['state']['size']} does not match the design's {d.n_state}")
    except KeyError as e:
        raise GainSetError(f"{where}: field '{field}': missing {e}") from None
    except (TypeError, ValueError, AttributeError) as e:
        raise GainSetError(f"{where}: field '{field}': {e}") from None
    return d, doc["provenance"], {k: v for k, v in doc["gps"].items()
                                  if k not in ("model", "latency_compensated_s", "latency_samples")}


_OPTIONAL = ("telemetry_chi2_on", "telemetry_chi2_full")


def _apply_calibration(d: EcuDesign, values: dict) -> EcuDesign:
    """The calibration list is authoritative: a calibrator may have edited it."""
    cal = d.calibration()
    # beta_telemetry's ends may be absent (a gain set of an ECU without that output): the design's defaults
    values = {**{c.name: c.value for c in cal if c.name in _OPTIONAL}, **values}
    missing = [c.name for c in cal if c.name not in values]
    if missing:
        raise GainSetError(f"no value for {', '.join(missing)}")
    for c in cal:  # the limits the A2L declares: a value outside them is refused, not clipped
        v = values[c.name]
        if not (isinstance(v, (int, float)) and c.lower <= v <= c.upper):
            raise GainSetError(f"'{c.name}' is {v!r}, outside its limits [{c.lower:g}, {c.upper:g}] {c.unit}")
    ctl = dataclasses.replace(d.controller, **{c.name: float(values[c.name]) for c in cal if c.owner == "controller"})
    noise_values: dict[str, Any] = {c.name: float(values[c.name]) for c in cal if c.owner == "noise"}
    noise = dataclasses.replace(d.filter.noise, **noise_values)
    filt: FilterDesign = dataclasses.replace(d.filter, noise=noise)
    ecu: dict[str, Any] = {c.name: float(values[c.name]) for c in cal if c.owner == "ecu"}
    return dataclasses.replace(d, filter=filt, controller=ctl, **ecu)
