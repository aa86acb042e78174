"""The ``evstab`` command line.

Every command accepts a bundled vehicle name or a TOML path. Bad input exits
with status 2 and one message naming the file/field/option and what was
expected; nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from evstab.controllers.two_dof import FRICTION_MARGIN, REFERENCE_MODELS
from evstab.plants import bundled_vehicles, is_multibody, load_vehicle
from evstab.plants.disturbances import Disturbances, Friction, default_wind
from evstab.plants.errors import EvstabError
from evstab.plants.maneuvers import MANEUVERS, make_maneuver
from evstab.plants.sensors import SensorConfig

from .cli_logs import cmd_convert, cmd_emulate, cmd_estimate, cmd_replay, command_line
from .cli_types import (PLANT_HELP as _PLANT_HELP, finite as _finite, nonneg as _nonneg, outage as _outage,
                        plant as _plant, positive as _positive, speed_kmh as _speed_kmh)


def _shorten(text: str, limit: int) -> str:
    """``text``, or its words up to ``limit`` characters followed by "..." (never cut mid-word)."""
    if len(text) <= limit:
        return text
    return text[:limit + 1].rsplit(" ", 1)[0].rstrip(",;:(") + " ..."


def cmd_vehicles(args) -> int:
    for key in bundled_vehicles():
        p = load_vehicle(key)
        print(f"{key:12s} m={p.mass:7.1f} kg  L={p.wheelbase:.3f} m  Cf/Cr={p.cornering_stiffness_front:.0f}/"
              f"{p.cornering_stiffness_rear:.0f} N/rad per tire  K_us={np.degrees(p.understeer_gradient):.3f} "
              f"deg/(m/s^2)  -- {_shorten(p.source, 90)}")
    return 0


def cmd_simulate(args) -> int:
    from .loop.plotting import plot_run
    from .loop.simulator import simulate

    p = load_vehicle(args.vehicle)
    speed = args.speed / 3.6
    amplitude = None if args.amplitude is None else np.radians(args.amplitude)
    man = make_maneuver(args.maneuver, p, speed, amplitude)
    if man.open_loop:  # a road-wheel angle no car has: refused before the run, with the limit
        from .logs.drivelog import PLAUSIBLE
        peak = float(np.max(np.abs(man.steer(np.linspace(0.0, man.duration, 20001)))))
        limit = PLAUSIBLE["steer"][1]
        if peak > limit:
            ratio = f" (this vehicle's steering ratio: {p.steering_ratio:g})" if p.steering_ratio else ""
            raise EvstabError(f"{man.name}: asks {np.degrees(peak):.1f} deg of road-wheel angle, beyond the "
                              f"{np.degrees(limit):.1f} deg a car's front wheels turn; --amplitude is the front "
                              f"road-wheel angle in deg, not the hand-wheel angle{ratio}")
    mu = p.mu if args.mu is None else args.mu
    dist = Disturbances(wind=default_wind(p) if args.wind else None, friction=Friction(mu=mu))
    sensors = SensorConfig(gps_outages=tuple(args.gps_outage or ()))
    controller, estimator, design = _loop_choice(args)
    res = simulate(p, args.plant, man, disturbances=dist, sensors=sensors, seed=args.seed, dt=args.dt,
                   controller=controller, estimator=estimator, design=design)
    from .logs.drivelog import DriveLog, LogFormatError, check_ranges
    try:  # never write a log that the reader would refuse
        check_ranges(DriveLog(res.log_columns(), "the simulated run"))
    except LogFormatError as exc:
        tr = res.truth
        k = int(np.argmax(np.abs(tr["beta"])))
        if np.abs(tr["beta"][k]) > np.radians(60.0):  # the car spun: the run is right, the log cannot hold it
            raise EvstabError(f"{p.name} on {args.plant}, {man.name} at {args.speed:g} km/h: the car spins (sideslip "
                              f"{np.degrees(tr['beta'][k]):.0f} deg at t = {res.t[k]:.2f} s), beyond what a drive log "
                              f"holds ({str(exc).replace(' (a unit or scaling error?)', '')}); the manoeuvre asks more than the tyres give at this speed: lower "
                              f"--speed or --amplitude, or close the loop (--controller)") from None
        raise EvstabError(f"{p.name}: {exc}; the vehicle parameters do not describe a car that can drive this "
                          "manoeuvre") from None
    res.write_csv(args.out)
    if args.plot:
        plot_run(res, args.plot, man)
    tr = res.truth
    print(f"{p.name} on {args.plant}, {man.name} {args.speed:g} km/h mu={mu:g}: {len(res.t)} samples "
          f"({res.t[-1]:.2f} s); max |yaw rate| {np.degrees(np.abs(tr['yaw_rate']).max()):.2f} deg/s, "
          f"max |sideslip| {np.degrees(np.abs(tr['beta']).max()):.2f} deg, "
          f"max |ay| {np.abs(tr['ay']).max():.2f} m/s^2 -> {args.out}")
    return 0


def _loop_choice(args):
    """(controller, estimator, design) of a command with ``--controller``, ``--estimator`` and ``--design``:
    a design folder's ECU (its filter and controller as exported) or the named method and seed 003's gains."""
    if args.design is None:
        if args.estimator is not None and args.controller is None:
            raise EvstabError("--estimator names the filter in the stability loop; give --controller too")
        return args.controller, args.estimator or "dakf", None
    from .firmware.export import ecu_from_design
    if args.estimator is not None:
        raise EvstabError("--design runs the design folder's own filter; leave out --estimator")
    ecu, _ = ecu_from_design(args.design)
    return args.controller or "two-dof", ecu.filter, ecu


def _output_folder(path) -> None:
    """An output folder's path that names an existing file is refused as such (before any work)."""
    import os
    if os.path.exists(path) and not os.path.isdir(path):
        raise EvstabError(f"--out {path}: is a file; expected a folder to write into (created if it does not exist)")


def cmd_export(args) -> int:
    from .firmware.export import FORMATS, export_design

    _output_folder(args.out)
    formats = FORMATS if args.format == "all" else (args.format,)
    command = command_line()
    paths = export_design(args.design_dir, args.out, formats, args.precision, command, fmu=args.fmu)
    print(f"exported {args.design_dir} ({args.precision}): " + ", ".join(p.name for p in paths) + f" -> {args.out}")
    return 0


def cmd_fmvss126(args) -> int:
    import json

    from .verdicts.fmvss126 import run_series
    from .logs.drivelog import atomic_write
    from pathlib import Path

    from evstab.controllers.two_dof import TwoDofDesign

    p = load_vehicle(args.vehicle)
    if args.design is not None:
        from .firmware.export import ecu_from_design
        if args.estimator is not None:
            raise EvstabError("--design runs the design folder's own filter; leave out --estimator")
        design, _ = ecu_from_design(args.design)
        estimator = design.filter.method
    else:
        design = TwoDofDesign(p.as_nominal(), k_beta=args.k_beta, k_gamma=args.k_gamma,
                              yaw_priority=args.yaw_priority, reference_tau=args.reference_tau,
                              reference_model=args.reference_model,
                              friction_margin=args.friction_margin, disturbance_filter_tau=args.disturbance_filter)
        estimator = args.estimator or "dakf"
    a_deg, rows, verdict = run_series(p, args.controller, estimator, args.mu, plant=args.plant,
                                      quick=args.quick, seed=args.seed, design=design)
    out = Path(args.out)
    keys = list(rows[0])
    lines = [",".join(keys)] + [",".join(str(r[k]).lower() if isinstance(r[k], bool) else
                                         (f"{r[k]:.6g}" if isinstance(r[k], float) else str(r[k])) for k in keys)
                                for r in rows]
    atomic_write(out / "fmvss126.csv", lambda fh: fh.write("\n".join(lines) + "\n"))
    atomic_write(out / "verdict.json", lambda fh: fh.write(json.dumps(verdict, indent=2) + "\n"))
    n_pass = sum(r["pass"] for r in rows)
    print(f"{p.name} on {args.plant}, FMVSS 126, controller {args.controller}: A = {a_deg:.1f} deg hand-wheel, {n_pass}/{len(rows)} "
          f"runs pass -> {'PASS' if verdict['pass'] else 'FAIL ' + ', '.join(verdict['failed_criteria'])} ({out})")
    return 0


def cmd_score_swd(args) -> int:
    from .verdicts.fmvss126 import score_swd
    from .logs.drivelog import read_log_csv

    p = load_vehicle(args.vehicle)
    p.require("steering_ratio", model="FMVSS 126 scoring")
    log = read_log_csv(args.log)
    steer = log["steer_driver"] if "steer_driver" in log else log["steer"]
    if "ay" not in log:
        from .logs.drivelog import LogFormatError
        raise LogFormatError(f"{args.log}: scoring needs the lateral acceleration column 'ay'")
    try:
        sc = score_swd(log["t"], steer * p.steering_ratio, log["yaw_rate"], log["ay"])
    except (ValueError, IndexError) as exc:  # not a sine-with-dwell run (too short, no 5 deg steer)
        raise EvstabError(f"{args.log}: cannot score it as a sine with dwell ({exc})") from None
    amp = float(np.degrees(np.max(np.abs(steer)) * p.steering_ratio))
    line = (f"BOS {sc.bos:.3f} s, COS {sc.cos:.3f} s, amplitude {amp:.1f} deg: yaw ratio {sc.yaw_ratio_1_0:.1f} % at "
            f"COS+1.0 s, {sc.yaw_ratio_1_75:.1f} % at COS+1.75 s, lateral displacement "
            f"{sc.lateral_displacement_m:.2f} m at BOS+1.07 s")
    if args.a_deg is not None:
        ok, failed = sc.passes(amp, args.a_deg)
        line += f" -> {'PASS' if ok else 'FAIL ' + ', '.join(failed)}"
    print(line)
    return 0


class _Help(argparse.HelpFormatter):
    """Help that states each option's default (where it has one that is not "none given")."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if (d is not None and d is not False and d is not argparse.SUPPRESS and "default" not in text
                and action.option_strings and not isinstance(d, list)):
            text += f" (default: {d})"
        return text


class _Parser(argparse.ArgumentParser):
    """A sub-command's parser: its help states each default (:class:`_Help`)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Help)
        super().__init__(*args, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    from .estimation.spec import LOOP_METHODS

    ap = argparse.ArgumentParser(prog="evstab", description="Stability-control design for in-wheel-motor EVs.")
    from evstab import __version__
    ap.add_argument("--version", action="version", version=f"evstab {__version__}")
    sub = ap.add_subparsers(dest="command", required=True,
                            parser_class=_Parser)
    sp = sub.add_parser("vehicles", help="list the bundled vehicle parameter sets")
    sp.set_defaults(func=cmd_vehicles)
    sp = sub.add_parser("simulate", help="simulate a manoeuvre and write a drive-log CSV")
    sp.add_argument("--vehicle", required=True, help=f"bundled name ({', '.join(bundled_vehicles())}) or TOML path")
    sp.add_argument("--plant", type=_plant, default="two-track", help=_PLANT_HELP + "; default two-track")
    sp.add_argument("--maneuver", choices=MANEUVERS, required=True, help="manoeuvre")
    sp.add_argument("--speed", type=_speed_kmh, required=True, help="speed [km/h], 0-300")
    sp.add_argument("--amplitude", type=_finite, help="front road-wheel angle amplitude [deg]")
    sp.add_argument("--mu", type=_positive, help="tire-road friction (default: the vehicle's)")
    sp.add_argument("--wind", action="store_true", help="lateral wind gust 4-8 s (seed 003)")
    sp.add_argument("--gps-outage", type=_outage, action="append", metavar="START:END",
                    help="GPS outage window [s]; repeatable")
    sp.add_argument("--controller", choices=["none", "yaw-pi", "two-dof", "two-dof-true"],
                    help="close the stability loop (sensors -> estimator -> controller -> actuators); "
                         "default: no loop, the driver alone")
    sp.add_argument("--estimator", choices=LOOP_METHODS,
                    help="the ECU's filter in the loop (default dakf; needs --controller)")
    sp.add_argument("--design", help="an 'evstab design' folder: its ECU (filter, controller, calibration, "
                                     "schedule, as exported) closes the loop; --controller defaults to two-dof")
    sp.add_argument("--seed", type=int, default=0, help="seed of every noise source")
    sp.add_argument("--dt", type=_positive, default=1e-3, help="time step [s]")
    sp.add_argument("--out", required=True, help="drive-log CSV to write")
    sp.add_argument("--plot", help="PNG figure to write")
    sp.set_defaults(func=cmd_simulate)
    from .estimation import METHODS
    from .estimation.spec import method_help
    sp = sub.add_parser("estimate", help="estimate sideslip, yaw rate and yaw from a drive log")
    sp.add_argument("log", help="drive log: CSV (the schema of docs/formats.md), .csv.gz, or .mf4/.mat/CSV with "
                                "--map")
    sp.add_argument("--vehicle", help="bundled name or TOML path (its nominal parameters are used)")
    sp.add_argument("--design", help="an 'evstab design' folder: run its estimator exactly as exported "
                                     "(instead of --vehicle/--method)")
    sp.add_argument("--method", choices=METHODS, default="dakf", help=method_help())
    sp.add_argument("--gps-latency", type=_nonneg, default=0.0, help="age of each GPS fix when logged [s]")
    sp.add_argument("--map", "--channel-map", dest="channel_map",
                    help="for a log with its own channels (.mf4, .mat, CSV): TOML naming the channel of each schema "
                         "column (docs/formats.md)")
    sp.add_argument("--trust-units", action="store_true",
                    help="skip the unit checks by consistency (gyro against GPS course, speed against GPS speed)")
    sp.add_argument("--no-monitor", action="store_true",
                    help="feed the log to the filter as it is: no sensor-fault screening, no fault_* columns")
    sp.add_argument("--noise", help="noise file (TOML, from --tune): the filter's noise settings; default the method's")
    sp.add_argument("--bias-learn-rate", type=_nonneg, metavar="RAD_S",
                    help="learn the gyro bias in full only below this yaw rate and not from twice it (0: everywhere, "
                         "the default; 0.2 on real drives with a nominal model from a data sheet, docs/estimators.md)")
    sp.add_argument("--tune", action="store_true",
                    help="fit the filter's noise intensities to the log (innovation maximum likelihood: gyro and GPS "
                         "velocity noise, process noise) and write them as a noise file to --out, which "
                         "'evstab estimate --noise' and 'evstab design --noise' read")
    sp.add_argument("--calibration", help="start the filter's gyro bias from this calibration file (TOML, from "
                                          "--save-calibration of an earlier drive)")
    sp.add_argument("--save-calibration", help="also write the gyro bias learnt over this drive as a calibration file")
    sp.add_argument("--out", required=True, help="estimate CSV to write (with --tune: the noise file)")
    sp.set_defaults(func=cmd_estimate)
    sp = sub.add_parser("replay", help="run a design's estimator and controller over a drive log (open loop)")
    sp.add_argument("log", help="drive-log CSV (the schema of docs/formats.md; steer_driver, steer_limited_last and "
                                "yaw_moment_limited_last are read when present)")
    sp.add_argument("--design", required=True, help="an 'evstab design' folder")
    sp.add_argument("--mu", type=_positive, help="friction the reference assumes (default: the vehicle's)")
    sp.add_argument("--out", required=True, help="CSV of the ECU outputs to write")
    sp.add_argument("--inputs-out", help="also write the ECU input rows (for the exported evstab_replay harness)")
    sp.add_argument("--map", "--channel-map", dest="channel_map",
                    help="for a log with its own channels (.mf4, .mat, CSV): TOML naming the channel of each schema "
                         "column (docs/formats.md)")
    sp.add_argument("--trust-units", action="store_true",
                    help="skip the unit checks by consistency (gyro against GPS course, speed against GPS speed)")
    sp.set_defaults(func=cmd_replay)
    sp = sub.add_parser("convert", help="a log with its own channels (MDF4, MATLAB .mat, CSV, a ROS 2 bag, a CAN "
                                        "trace with its DBC; with a channel map), or "
                                        "an NMEA 0183 GNSS log and an IMU CSV, to a drive-log CSV")
    sp.add_argument("log", nargs="?", help="log to convert (.mf4, .mat, .csv, a ROS 2 bag .mcap, or a CAN trace "
                                           ".blf/.asc with --dbc; with --map)")
    sp.add_argument("--mcap", help="a ROS 2 bag (MCAP) to convert, as the log argument; the map names TOPIC.FIELD "
                                   "channels (docs/formats.md)")
    sp.add_argument("--can", help="a CAN trace (.blf, .asc) to convert, as the log argument; with --dbc")
    sp.add_argument("--dbc", help="the car's DBC that decodes a CAN trace (.blf, .asc); the map names DBC signals "
                                  "(SIGNAL or MESSAGE.SIGNAL)")
    sp.add_argument("--map", "--channel-map", dest="channel_map",
                    help="TOML: the channel, unit, scale and sign of each schema column, and the time base "
                         "(docs/formats.md)")
    sp.add_argument("--nmea", help="NMEA 0183 log (RMC/VTG/GGA/GSA/HDT; checksums verified)")
    sp.add_argument("--imu", help="with --nmea: IMU CSV, the drive-log schema's columns without the GPS ones")
    sp.add_argument("--time-offset", type=_finite, default=0.0,
                    help="GPS time [s from 00:00 UTC] minus IMU time t (default 0: t is UTC seconds of day)")
    sp.add_argument("--out", required=True, help="drive-log CSV to write")
    sp.set_defaults(func=cmd_convert)
    sp = sub.add_parser("emulate", help="production sensors on a reference log: a single-antenna GPS course and "
                                        "speed, and a production gyro, drawn from the reference yaw rate and sideslip")
    sp.add_argument("log", help="reference log (drive-log CSV with beta_true; or any file with --map)")
    sp.add_argument("--map", "--channel-map", dest="channel_map", help="channel map for a log that is not a drive log")
    sp.add_argument("--gps-rate", type=_positive, default=5.0, help="course fixes per second [Hz]")
    sp.add_argument("--gps-offset", type=_nonneg, default=0.0, help="time of the first fix after the first row [s]")
    sp.add_argument("--gps-velocity-noise", type=_nonneg, default=0.04,
                    help="receiver velocity noise per axis at HDOP 1 [m/s]; course noise = this x HDOP / speed")
    sp.add_argument("--gps-course-noise", type=_nonneg, default=0.0,
                    help="a fixed course noise per fix instead [deg] (0: from the velocity noise)")
    sp.add_argument("--gps-latency", type=_nonneg, default=0.0, help="age of each fix when logged [s]")
    sp.add_argument("--gyro", choices=["reference", "production"], default="reference",
                    help="the log's yaw rate as it is, or a production sensor (default bias 3 mrad/s, scale +1 %%, "
                         "noise 1.5 mrad/s)")
    sp.add_argument("--gyro-bias", type=_finite, help="production gyro bias [rad/s]")
    sp.add_argument("--gyro-scale", type=_finite, help="production gyro scale error [-] (0.01: reads 1 %% high)")
    sp.add_argument("--gyro-noise", type=_nonneg, help="production gyro white noise per sample [rad/s]")
    sp.add_argument("--gyro-quantum", type=_nonneg, help="production gyro resolution [deg/s] (a CAN signal's step)")
    sp.add_argument("--seed", type=int, default=0, help="seed of the emulated noise")
    sp.add_argument("--out", required=True, help="drive-log CSV to write (and OUT.emulation.json, what was emulated)")
    sp.set_defaults(func=cmd_emulate)
    sp = sub.add_parser("export", help="export a design as firmware: C99, JSON gain set, A2L, CDFX")
    sp.add_argument("design_dir", help="an 'evstab design' folder")
    sp.add_argument("--format", choices=["c", "json", "a2l", "cdfx", "all"], default="all", help="what to write")
    sp.add_argument("--precision", choices=["float32", "float64"], default="float64",
                    help="floating-point type of the C code and the A2L record layouts")
    sp.add_argument("--out", required=True, help="folder to write into")
    sp.add_argument("--fmu", action="store_true",
                    help="also write evstab_ecu.fmu: the step as an FMI 2.0 co-simulation FMU (built with the host's C "
                         "compiler; binary for this platform, sources inside for others)")
    sp.set_defaults(func=cmd_export)
    sp = sub.add_parser("fmvss126", help="FMVSS 126: slowly increasing steer for A, then the sine-with-dwell series")
    sp.add_argument("--vehicle", required=True, help="bundled name or TOML path (the controller's nominal model)")
    sp.add_argument("--plant", type=_plant, default="two-track", help=_PLANT_HELP + "; default two-track")
    sp.add_argument("--controller", choices=["none", "yaw-pi", "two-dof"], default="two-dof",
                    help="the stability loop's controller")
    sp.add_argument("--estimator", choices=LOOP_METHODS, help="the ECU's filter (default dakf)")
    sp.add_argument("--design", help="an 'evstab design' folder: its ECU as exported (instead of --estimator "
                                     "and the design knobs below)")
    sp.add_argument("--mu", type=_positive, help="friction (default: the vehicle's)")
    sp.add_argument("--seed", type=int, default=0, help="seed of every noise source")
    sp.add_argument("--quick", action="store_true", help="only the first two amplitudes at or above 5 A")
    sp.add_argument("--k-beta", type=_positive, default=5.0, help="model-following pole for sideslip [rad/s]")
    sp.add_argument("--k-gamma", type=_positive, default=5.0, help="model-following pole for yaw rate [rad/s]")
    sp.add_argument("--yaw-priority", type=_positive, default=4.0, help="yaw weight when a command saturates")
    sp.add_argument("--reference-tau", type=_positive, default=0.1, help="reference lag [s]")
    sp.add_argument("--reference-model", choices=REFERENCE_MODELS, default="linear",
                    help="the law's reference: the nominal linear car (default) or seed 003's static reference "
                         "through the lag")
    sp.add_argument("--friction-margin", type=_positive, default=FRICTION_MARGIN, help="yaw-rate reference limit, share of mu g / v")
    sp.add_argument("--disturbance-filter", type=_nonneg, default=0.0, help="low-pass on the disturbance estimates [s]")
    sp.add_argument("--out", required=True, help="folder for fmvss126.csv and verdict.json")
    sp.set_defaults(func=cmd_fmvss126)
    sp = sub.add_parser("derive-nominal", help="the nominal vehicle file of a CommonRoad multi-body car "
                                               "(geometry from its set, cornering stiffness identified)")
    sp.add_argument("plant", type=_plant, help="commonroad-mb:N")
    sp.add_argument("--out", required=True, help="vehicle TOML to write")
    sp.set_defaults(func=cmd_derive_nominal)
    sp = sub.add_parser("design", help="design, analyse, sweep and tune the estimator and controller; write the report")
    sp.add_argument("--vehicle", required=True, help="bundled name or TOML path (what the design believes)")
    sp.add_argument("--plant", type=_plant, default="two-track",
                    help=_PLANT_HELP + "; the car the sweep, tuning, responses and FMVSS 126 run on; default two-track")
    sp.add_argument("--out", required=True, help="folder for design.json, sweep.csv, report.html, report.md")
    sp.add_argument("--quick", action="store_true", help="fewer cases and tuning iterations (under a minute)")
    sp.add_argument("--executor", choices=["local", "dask"], default="local",
                    help="local process pool (default) or a Dask distributed cluster")
    sp.add_argument("--scheduler", help="Dask scheduler address (default: a local cluster)")
    sp.add_argument("--workers", type=int, help="worker processes (default: the CPU count)")
    sp.add_argument("--no-progress", action="store_true", help="no progress bar")
    sp.add_argument("--noise", help="noise file (TOML, from 'evstab estimate --tune'): the filter's noise settings; "
                                    "default the method's")
    sp.add_argument("--no-kinematic-path", action="store_true",
                    help="the ECU's filter without the kinematic sideslip path (by default it blends in a_y/v - r "
                         "where the tyres leave the linear model; design.json records which)")
    sp.set_defaults(func=cmd_design)
    sp = sub.add_parser("cache", help="where the compiled code is cached ($EVSTAB_CACHE, default ~/.cache/evstab), "
                                      "how much, and --clear to empty it")
    sp.add_argument("--clear", action="store_true", help="delete the cached generated C and libraries")
    sp.set_defaults(func=cmd_cache)
    sp = sub.add_parser("report", help="redraw report.md and report.html from a design folder (no recomputing)")
    sp.add_argument("dir", help="folder written by 'evstab design'")
    sp.set_defaults(func=cmd_report)
    sp = sub.add_parser("score-swd", help="score a recorded or simulated sine-with-dwell log (FMVSS 126)")
    sp.add_argument("log")
    sp.add_argument("--vehicle", required=True, help="for the steering ratio")
    sp.add_argument("--a-deg", type=_positive, help="the vehicle's A [deg hand-wheel], to apply the criteria")
    sp.set_defaults(func=cmd_score_swd)
    return ap


def cmd_derive_nominal(args) -> int:
    from .design.nominal import write_nominal
    if not is_multibody(args.plant):
        raise EvstabError(f"derive-nominal takes a commonroad-mb:N plant, not '{args.plant}'")
    p = write_nominal(args.plant, args.out)
    print(f"{args.plant}: m {p.mass:.1f} kg, I_z {p.yaw_inertia:.1f} kg m^2, lf/lr {p.lf:.3f}/{p.lr:.3f} m, "
          f"C_f/C_r {p.cornering_stiffness_front:.0f}/{p.cornering_stiffness_rear:.0f} N/rad per tyre "
          f"(identified), K_us {np.degrees(p.understeer_gradient):.3f} deg/(m/s^2) -> {args.out}")
    return 0


def cmd_design(args) -> int:
    from .design.design_job import run_design
    if args.workers is not None and args.workers < 1:
        raise EvstabError(f"--workers must be >= 1, got {args.workers}")
    if args.scheduler and args.executor != "dask":
        raise EvstabError("--scheduler needs --executor dask")
    _output_folder(args.out)
    command = command_line()
    noise = None
    if args.noise:
        from .estimation.noise_fit import load_noise
        noise = load_noise(args.noise)
    doc = run_design(args.vehicle, args.out, quick=args.quick, executor=args.executor, scheduler=args.scheduler,
                     workers=args.workers, command=command, progress=not args.no_progress, plant=args.plant,
                     noise=noise, kinematic=not args.no_kinematic_path)
    from .design.record import design_points
    s, d = doc["sweep"], design_points(doc)["tuned"]
    print(f"{doc['vehicle']['name']}: tuned K_beta {d['k_beta']:.4g}, K_gamma {d['k_gamma']:.4g} rad/s; "
          f"worst-case cost over {s['cases']} cases: paper {s['paper']['worst_cost']:.4g}, tuned "
          f"{s['tuned']['worst_cost']:.4g}; stable cases: paper {s['paper']['stable_cases']}, tuned "
          f"{s['tuned']['stable_cases']} -> {args.out}/report.html")
    return 0


def cmd_cache(args) -> int:
    from .kernels.compiled import _cache_dir, cache_files, clear_cache
    d = _cache_dir()
    if args.clear:
        n, size = clear_cache()
        print(f"removed {n} files ({size / 2**20:.1f} MiB) from {d}")
        return 0
    files = cache_files()
    size = sum(p.stat().st_size for p in files)
    print(f"{d}: {len(files)} files, {size / 2**20:.1f} MiB (set EVSTAB_CACHE to move it; "
          "'evstab cache --clear' empties it)")
    return 0


def cmd_report(args) -> int:
    from .design.report import write_report
    try:
        md, html = write_report(args.dir)
    except FileNotFoundError as exc:
        raise EvstabError(str(exc)) from None
    print(f"wrote {md} and {html}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except EvstabError as exc:
        print(f"evstab {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"evstab {args.command}: error: {exc.filename or ''}: {exc.strerror}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
