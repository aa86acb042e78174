"""The ``evstab`` commands that read drive logs: ``estimate``, ``replay``, ``convert`` and ``emulate``
(:mod:`toolkit.cli` builds the parser and runs them)."""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.errors import EvstabError


def command_line() -> str | None:
    """The command as typed (each argument shell-quoted), for the provenance of what it writes; None when run
    from Python without arguments."""
    import shlex
    return "evstab " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:] else None


def _check_log(log, args, params=None) -> None:
    """Unit mistakes found by consistency (:func:`toolkit.logs.drivelog.check_units`; with the vehicle ``params`` also
    :func:`toolkit.logs.drivelog.check_steer`), and a log without a usable GPS fix; ``--trust-units`` skips the unit
    checks."""
    from .logs.drivelog import check_steer, check_units
    if not np.any(np.isfinite(log["gps_course"])):
        raise EvstabError(f"{log.source}: no GPS fix (column 'gps_course' is empty on every row): nothing to "
                          "correct the gyro with; for a log made by 'evstab convert --nmea', check --time-offset")
    if not getattr(args, "trust_units", False):
        check_units(log)
        if params is not None:
            check_steer(log, params.wheelbase, params.understeer_gradient)


def cmd_estimate(args) -> int:
    from .estimation import design_filter, run_estimator
    from .estimation.kalman import OUTPUTS
    from .logs.channels import read_log
    from .logs.drivelog import write_log_table

    if (args.vehicle is None) == (args.design is None):
        raise EvstabError("give --vehicle (a filter designed from its nominal parameters) or --design (the "
                          "filter of an 'evstab design' folder, as exported), not both")
    if args.design is not None:
        return _estimate_designed(args)
    p = load_vehicle(args.vehicle)
    from .estimation.monitor import FLAGS

    # plus the schema's required columns; the monitor reads ax, the GPS columns and gps_time_fault
    needed = ("yaw_moment", "gps_hdop", "gps_sats", "ay", "ax", "gps_speed", "gps_heading", "gps_time_fault",
              "roll_rate", "gps_roll")
    log = read_log(args.log, needed, args.channel_map).without_truth()
    _check_log(log, args, p.as_nominal())
    from .estimation.spec import METHOD_COLUMNS
    lacks = [c for c in METHOD_COLUMNS.get(args.method, ()) if not np.any(np.isfinite(log.columns.get(c, [np.nan])))]
    if lacks:
        raise EvstabError(f"{args.log}: method '{args.method}' needs column(s) {', '.join(lacks)}, which the log "
                          f"lacks (or has no value in)")
    noise = None
    if args.noise:
        from .estimation.noise_fit import load_noise
        noise = load_noise(args.noise)
    d = design_filter(args.method, p, noise, latency=args.gps_latency)
    if args.bias_learn_rate is not None:
        if not d.bias:
            raise EvstabError(f"'{args.method}' has no gyro-bias state: --bias-learn-rate goes with dakf, amrkf, "
                              f"kf-bias, mbkf or double-layer")
        d = dataclasses.replace(d, noise=dataclasses.replace(d.noise, bias_learn_rate=args.bias_learn_rate))
    if args.tune:
        return _tune_noise(args, d, log)
    bias = None
    if args.calibration or args.save_calibration:
        if not d.bias:
            raise EvstabError(f"'{args.method}' has no gyro-bias state: --calibration and --save-calibration go with "
                              f"dakf, amrkf, kf-bias, mbkf or double-layer")
        if args.calibration:
            from .estimation.calibration import load_calibration
            bias = load_calibration(args.calibration)
    est = run_estimator(d, log, monitor=not args.no_monitor, bias=bias)
    _require_finite(args.log, est.t, {"beta": est["beta"], "yaw_rate": est["yaw_rate"]})
    cols = {"t": est.t}
    for name in OUTPUTS:
        v = est[name]
        if name not in ("bias_alarm", "gyro_resid", "gyro_var", "course_var") and np.any(np.isfinite(v)):
            # a method's columns only
            cols[name] = v
    flagged = {}
    if not args.no_monitor:
        for name in FLAGS:
            cols[name] = est[name]
            flagged[name] = int(est[name].sum())
    write_log_table(args.out, cols)
    if args.save_calibration:
        from .estimation.calibration import write_calibration
        if est.final is None:
            raise EvstabError(f"--save-calibration: method '{args.method}' has no gyro-bias estimate to save")
        write_calibration(args.save_calibration, est.final["gyro_bias"], est.final["gyro_bias_std"],
                          command_line() or "evstab estimate")
    fixes = int(np.isfinite(log["gps_course"]).sum())
    used = int(np.nansum(est["gps_used"]))
    faults = ", ".join(f"{k[6:]} {v}" for k, v in flagged.items() if v)
    print(f"{args.method} on {args.log}: {len(est.t)} samples, {fixes} GPS fixes, {used} used "
          f"({est.backend} backend)" + (f"; rows flagged: {faults}" if faults else
                                        ("; no sensor fault flagged" if flagged else "")) + f" -> {args.out}")
    if args.method != "lob":
        from .estimation.diagnostics import course_report
        print("  " + course_report(est.columns, t=est.t))
    return 0


ESTIMATE_COLUMNS = ("beta", "yaw_rate", "yaw", "d1", "d2", "gyro_bias", "beta_std", "gps_used")


def _replay(args):
    from .ecu.step import OUTPUTS
    from .firmware.export import ecu_from_design
    from .firmware.replay import LOG_COLUMNS, ecu_inputs, ecu_program, for_log_periods
    from .logs.channels import read_log

    d, _ = ecu_from_design(args.design)
    log = read_log(args.log, LOG_COLUMNS, args.channel_map).without_truth()
    _check_log(log, args, d.controller.params)
    mu = d.controller.params.mu if getattr(args, "mu", None) is None else args.mu
    U = ecu_inputs(log, mu, d.filter.dt_nominal, d.wheel_radius)
    prog = ecu_program(for_log_periods(d, U))
    Y = prog.run(U)
    _require_finite(args.log, log["t"], {name: OUTPUTS.columns(Y)[name] for name in
                                         ("beta", "yaw_rate", "steer_cmd", "yaw_moment_cmd")})
    return d, log, U, Y, prog.backend


def _require_finite(source, t, signals: dict) -> None:
    """Refuse to write estimates or commands that stopped being numbers (a filter that diverged on the
    log or on the vehicle's parameters), naming the first row."""
    for name, v in signals.items():
        bad = np.flatnonzero(~np.isfinite(v))
        if len(bad):
            k = int(bad[0])
            raise EvstabError(f"{source}: row {k + 2} (t = {float(t[k])!r} s): the {name} estimate is not finite; "
                              f"the filter diverged (check the log's units and the vehicle parameters)")


def _tune_noise(args, d, log) -> int:
    from .estimation.noise_fit import METHODS, fit_noise, write_noise
    if d.method not in METHODS:
        raise EvstabError(f"--tune fits the noise of the Kalman methods ({', '.join(METHODS)}), "
                          f"not '{d.method}'")
    fit = fit_noise(d, log)
    write_noise(args.out, fit, d.noise, f"evstab estimate --tune {args.log} --vehicle {args.vehicle} "
                                        f"--method {d.method}")
    lo, hi = fit.nis_interval
    print(f"{d.method} noise fitted to {args.log}: {fit.gyro_updates} gyro updates, {fit.course_fixes} course fixes, "
          f"{fit.evaluations} filter runs; -2 log L per innovation {fit.nll_start:.5g} -> {fit.nll:.5g}; mean NIS "
          f"{fit.nis_start:.3f} -> {fit.nis:.3f} (95 % interval [{lo:.3f}, {hi:.3f}])")
    for k, a, b in zip(fit.parameters, fit.start, fit.values):
        note = " (at its bound: the log does not pin it)" if k in fit.at_bound else ""
        print(f"  {k:18s} {a:11.4g} -> {b:11.4g}{note}")
    warning = tune_warning(fit)
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    print(f"-> {args.out}")
    return 0


def tune_warning(fit) -> str | None:
    """A warning when the fitted noise makes the course innovations less consistent than the noise it
    started from (mean NIS further from 1, or out of its 95 % interval where it was inside): the
    likelihood then rewards the log's particulars (a short log pins the parameters poorly)."""
    lo, hi = fit.nis_interval
    inside_before, inside_after = lo <= fit.nis_start <= hi, lo <= fit.nis <= hi
    if abs(fit.nis - 1.0) <= abs(fit.nis_start - 1.0) and (inside_after or not inside_before):
        return None
    return (f"the fitted noise makes the course innovations less consistent than the noise it started from "
            f"(mean NIS {fit.nis_start:.3f} -> {fit.nis:.3f}, 95 % interval [{lo:.3f}, {hi:.3f}]) over "
            f"{fit.course_fixes} course fixes: check the fit on another log before using it, or keep the "
            f"method's noise")


def _estimate_designed(args) -> int:
    from .ecu.step import INPUTS, OUTPUTS
    from .logs.drivelog import write_log_table

    if args.method != "dakf" or args.gps_latency != 0.0 or args.noise or args.tune:
        raise EvstabError("--method, --gps-latency and the noise (--noise, --tune) come from the design with --design; "
                          "leave them out")
    d, log, U, Y, backend = _replay(args)
    cols = {"t": log["t"]}
    cols.update({name: OUTPUTS.columns(Y)[name] for name in ESTIMATE_COLUMNS + ("beta_telemetry",)})
    write_log_table(args.out, cols)
    print(f"{d.filter.method} (designed, {args.design}) on {args.log}: {len(U)} samples, "
          f"{int(INPUTS.columns(U)['gps_valid'].sum())} GPS fixes, {int(cols['gps_used'].sum())} used ({backend} backend) -> {args.out}")
    return 0


def cmd_replay(args) -> int:
    from .firmware.csource import write_inputs_csv
    from .ecu.step import OUTPUTS
    from .logs.drivelog import atomic_write, write_log_table

    d, log, U, Y, backend = _replay(args)
    cols = {"t": log["t"]}
    cols.update(OUTPUTS.columns(Y))
    if args.inputs_out:
        atomic_write(args.inputs_out, lambda fh: write_inputs_csv(fh, U))
    write_log_table(args.out, cols)
    i_n = OUTPUTS.index("yaw_moment_cmd")
    print(f"replay of {args.log} through {args.design}: {len(U)} samples ({backend} backend); max |steer_cmd| "
          f"{np.degrees(np.abs(OUTPUTS.columns(Y)['steer_cmd']).max()):.3f} deg, max |yaw_moment_cmd| "
          f"{np.abs(Y[:, i_n]).max():.1f} N m -> {args.out}")
    return 0


def cmd_convert(args) -> int:
    from .logs.channels import read_log
    from .logs.drivelog import REQUIRED, read_log_csv, write_log_csv
    from .logs.nmea import merge_onto_imu, read_nmea

    from .logs.channels import source_kind
    for flag, what in (("mcap", "an MCAP file (.mcap)"), ("can", "a CAN trace (.blf, .asc)")):
        given = getattr(args, flag)
        if given is None:
            continue
        if args.log is not None:
            raise EvstabError(f"--{flag} {given} and {args.log}: give one log to convert")
        if source_kind(given) != flag:
            raise EvstabError(f"--{flag} {given}: expected {what}")
        args.log = given
    if (args.log is None) == (args.nmea is None):
        raise EvstabError("give a log with --map (MDF4, MATLAB, CSV, a CAN trace or a ROS 2 bag, and the channel map "
                          "that names its channels), "
                          "or --nmea GPS.nmea with --imu IMU.csv")
    if args.nmea is not None:
        if args.imu is None or args.channel_map is not None:
            raise EvstabError("--nmea goes with --imu IMU.csv (and no --channel-map)")
        gps = read_nmea(args.nmea)
        imu = read_log_csv(args.imu, required=tuple(c for c in REQUIRED if c != "gps_course"))
        cols = {k: v for k, v in imu.columns.items() if not k.startswith("gps_")}
        merged, counts = merge_onto_imu(cols, gps, args.time_offset)
        if counts["placed"] == 0 and len(gps):
            t_imu = cols["t"]
            offset = float(gps.t[0] - t_imu[0])
            raise EvstabError(
                f"{args.nmea} + {args.imu}: none of the {len(gps)} GPS epochs falls inside the IMU log "
                f"(GPS time {gps.t[0]:.3f}-{gps.t[-1]:.3f} s, IMU t {t_imu[0]:.3f}-{t_imu[-1]:.3f} s with "
                f"--time-offset {args.time_offset:g}); --time-offset {offset:.3f} puts the first fix on the IMU "
                "log's first row (IMU t = GPS time - offset)")
        what = (f"{args.nmea} + {args.imu}: {len(gps)} GPS epochs, {counts['placed']} placed on {len(cols['t'])} IMU "
                f"rows, {counts['before']} before and {counts['after']} after the IMU log dropped"
                + (f", {counts['time_backwards']} with a time tag going backwards dropped (flagged in column "
                   f"gps_time_fault)" if counts["time_backwards"] else ""))
    else:
        if args.imu is not None or args.time_offset != 0.0:
            raise EvstabError("--imu and --time-offset go with --nmea")
        if args.channel_map is None:
            raise EvstabError(f"{args.log}: give --map MAP.toml, the channel map that names the file's channel for "
                              f"each drive-log column (docs/formats.md)")
        from pathlib import Path

        from .logs.channels import load_channel_map
        cmap = load_channel_map(args.channel_map)
        if args.dbc is not None:
            if source_kind(args.log) != "can":
                raise EvstabError(f"{args.log}: --dbc goes with a CAN trace (.blf, .asc)")
            cmap["dbc"] = Path(args.dbc)
        log = read_log(args.log, None, cmap)
        merged = log.columns
        what = f"{args.log}: {len(merged['t'])} rows"
        for line in log.notes:
            print(f"  {line}")
    write_log_csv(args.out, merged)
    fixes = int(np.isfinite(merged["gps_course"]).sum())
    truth = [c for c in merged if c.endswith("_true")]
    print(f"{what}; {fixes} GPS fixes" + (f"; reference {', '.join(truth)}" if truth else "") + f" -> {args.out}")
    if not fixes:
        print("  no GPS course: a reference log; 'evstab emulate' adds a receiver's course (and a production gyro)")
    return 0


def cmd_emulate(args) -> int:
    from .logs.emulate import PRODUCTION_GYRO, Emulation, emulate, write_metadata
    from .logs.channels import read_log
    from .logs.drivelog import write_log_csv

    log = read_log(args.log, None, args.channel_map)
    gyro: dict[str, Any] = dict(PRODUCTION_GYRO) if args.gyro == "production" else {"gyro": "reference"}
    for key, value in (("gyro_bias", args.gyro_bias), ("gyro_scale", args.gyro_scale),
                       ("gyro_noise", args.gyro_noise)):
        if value is not None:
            if args.gyro != "production":
                raise EvstabError(f"--{key.replace('_', '-')} goes with --gyro production")
            gyro[key] = value
    if args.gyro_quantum is not None:
        if args.gyro != "production":
            raise EvstabError("--gyro-quantum goes with --gyro production")
        gyro["gyro_quantum"] = float(np.radians(args.gyro_quantum))
    em = Emulation(seed=args.seed, gps_rate=args.gps_rate, gps_offset=args.gps_offset,
                   gps_velocity_noise=args.gps_velocity_noise, gps_course_noise=float(np.radians(args.gps_course_noise)),
                   gps_latency=args.gps_latency, **gyro)
    cols = emulate(log, em)
    write_log_csv(args.out, cols)
    write_metadata(args.out, em, str(args.log))
    print(f"{args.log}: {len(cols['t'])} rows, {int(np.isfinite(cols['gps_course']).sum())} GPS fixes emulated "
          f"({em.describe()}) -> {args.out}")
    return 0
