"""Closed stability loop speed: the compiled loop vs python-control, same loop, same process.

The loop: two-track plant -> sensors -> dakf -> 2-DOF controller -> actuators ->
plant, micro EV, 25 km/h, 5 deg step steer, wind, 1 kHz. evstab runs it as one
compiled casadi rollout (:func:`toolkit.closed_loop.compiled_loop_run`). The
reference builds the same loop in python-control: a discrete ``nlsys`` for the
plant (RK4 step of the same numpy model; it outputs the previous sample's truth,
the loop's sensor delay) and one for the ECU (sensor equations, the estimator step,
the control law and the actuator law, all the numpy forms of the functions the
compiled loop is traced from), joined by ``control.interconnect`` and run by
``control.input_output_response``. python-control is slow, so it runs the first
``--ref-seconds`` and is compared per step.

Run: ``python benchmarks/bench_closed_loop.py [--ref-seconds 0.5]``
"""

from __future__ import annotations

import argparse
import time

import control
import numpy as np

from controllers.actuators import ActuatorLimits, actuator_law
from controllers.two_dof import TwoDofDesign, control_law
from plants import DISTURBANCES, TRUTH, get_plant, load_vehicle
from plants.backend import NUMPY
from plants.disturbances import Disturbances, default_wind, disturbance_profile
from plants.maneuvers import step_steer
from plants.sensors import SensorConfig, gps_fix_mask, readings
from toolkit.closed_loop import NOISE, _noise_matrix, compiled_loop_run
from toolkit.compiled import compiled_plant, rk4_step, rk4_substeps
from toolkit.estimation import design_filter
from toolkit.estimation import kalman


def python_control_loop(p, man, dist, sens, seconds, dt=1e-3):
    model = get_plant("two-track")
    n_sub = rk4_substeps(model, p, dt)
    est = design_filter("dakf", p, dt=dt)
    ctl = TwoDofDesign(p.as_nominal(), dt=dt)
    lim = ActuatorLimits()
    tmax = p.max_motor_torque or 1e9
    nx, nt = len(model.states), len(TRUTH)

    def plant_upd(t, xs, u, params):
        x = xs[:nx]
        cmd, w = np.append(u[:4], 0.0), u[4:]  # steer_rate: the two-track takes the angle directly
        y = model.h(x, model.command_map(cmd, x, p), w, p)
        return np.concatenate([rk4_step(model, p, x, cmd, w, dt, n_sub), y])

    plant = control.nlsys(plant_upd, lambda t, xs, u, params: xs[nx:], dt=dt, name="plant",
                          inputs=["steer", "yaw_moment", "speed_ref", "drive_on"] + [f"w_{d}" for d in DISTURBANCES],
                          outputs=[f"y_{n}" for n in TRUTH], states=nx + nt)
    ne = kalman.layout(est)["size"]
    sizes = [ne, 6, 2, 2, 2]

    def ecu(t, zs, u):
        z_est, z_ctl, z_act = zs[:ne], zs[ne:ne + 6], zs[ne + 6:ne + 8]
        applied, flags = zs[ne + 8:ne + 10], zs[ne + 10:ne + 12]
        tr = dict(zip(TRUTH, u[:nt]))
        nzv = dict(zip(NOISE, u[nt:nt + len(NOISE)]))
        noise = {"steer": nzv["steer"], "gyro": nzv["gyro"], "roll_gyro": nzv["roll_gyro"],
                 "accel_x": nzv["accel_x"], "accel_y": nzv["accel_y"],
                 "wheel": [nzv[f"wheel_{c}"] for c in ("fl", "fr", "rl", "rr")], "speed": nzv["speed"],
                 "gps_e": nzv["gps_e"], "gps_n": nzv["gps_n"], "heading": nzv["heading"]}
        fix, steer_drv, bank = u[nt + len(NOISE)], u[nt + len(NOISE) + 1], u[nt + len(NOISE) + 2]
        m = readings(tr, {"steer": applied[0], "yaw_moment": applied[1], "bank": bank}, noise,
                     (tr["yaw"], tr["vx"], tr["vy"], tr["yaw_rate"]), fix, sens, p.wheel_radius, NUMPY)
        valid = float(m["gps_valid"])
        u_est = np.array([dt, m["speed"], m["steer"], m["yaw_moment"], m["yaw_rate"], valid,
                          valid * m["gps_course"], sens.gps_hdop if fix > 0.5 else 1.0,
                          float(sens.gps_sats) if fix > 0.5 else 99.0, m["ay"]])
        z_est_n, y = kalman.step(est, z_est, u_est, NUMPY, with_course=valid > 0.5)
        sig = np.array([m["speed"], steer_drv, y[0], y[1], y[4], y[5], dist.friction.mu, flags[0], flags[1]])
        z_ctl_n, uc = control_law(ctl, z_ctl, sig)
        z_act_n, a = actuator_law(p, lim, tmax, z_act, np.array([uc[0], uc[1], 0.0, dt]))
        return np.concatenate([z_est_n, z_ctl_n, z_act_n, a[:2], a[2:]]), a[:2]

    ecu_sys = control.nlsys(lambda t, z, u, params: ecu(t, z, u)[0], lambda t, z, u, params: ecu(t, z, u)[1],
                            dt=dt, name="ecu",
                            inputs=[f"y_{n}" for n in TRUTH] + [f"n_{k}" for k in NOISE] + ["fix", "steer_driver",
                                                                                              "bank"],
                            outputs=["steer", "yaw_moment"], states=sum(sizes))
    ext = (["speed_ref", "drive_on"] + [f"w_{d}" for d in DISTURBANCES] + [f"n_{k}" for k in NOISE]
           + ["fix", "steer_driver", "bank"])
    loop = control.interconnect([plant, ecu_sys], inplist=ext, outlist=[f"y_{n}" for n in TRUTH], dt=dt)
    n = int(round(seconds / dt))
    t = np.arange(n) * dt
    W = disturbance_profile(dist, t)
    U = np.vstack([np.full(n, man.speed), man.drive_on(t), W, _noise_matrix(sens, 0, int(round(man.duration / dt)))[:, :n],
                   gps_fix_mask(t, sens), man.steer(t), W[DISTURBANCES.index("bank")]])
    x0 = model.initial_state(p, man.speed)
    _, y0 = compiled_plant(model, p, dt).step(x0, np.array([0.0, 0.0, man.speed, 1.0, 0.0]), W[:, 0])
    z0 = np.zeros(sum(sizes))
    z0[:ne] = kalman.initial_state(est, 0.0, 0.0)
    t0 = time.perf_counter()
    resp = control.input_output_response(loop, t, U, np.concatenate([x0, y0, z0]))
    return time.perf_counter() - t0, resp


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ref-seconds", type=float, default=0.5)
    args = ap.parse_args(argv)
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=0.2, duration=10.0)
    dist = Disturbances(wind=default_wind(p))
    sens = SensorConfig()
    compiled_loop_run(p, man, disturbances=dist, sensors=sens)  # build and compile once
    best = np.inf
    for _ in range(5):
        t0 = time.perf_counter()
        r = compiled_loop_run(p, man, disturbances=dist, sensors=sens)
        best = min(best, time.perf_counter() - t0)
    n = len(r["t"])
    t_ref, resp = python_control_loop(p, man, dist, sens, args.ref_seconds)
    m = resp.outputs.shape[1]
    # python-control's outputs at sample k are the plant's delayed truth: compare with ours one sample earlier
    diff = np.abs(resp.outputs[TRUTH.index("yaw_rate"), 1:] - r["truth"]["yaw_rate"][:m - 1]).max()
    per_c, per_ref = best / n, t_ref / m
    print(f"closed loop, 10 s at 1 kHz: evstab compiled {best * 1e3:.1f} ms per run ({per_c * 1e6:.2f} us/step); "
          f"python-control interconnect + input_output_response {per_ref * 1e6:.0f} us/step over {args.ref_seconds:g} s "
          f"-> ratio {per_ref / per_c:.0f}x (target 250x, <= 5 ms per run); yaw-rate difference {diff:.1e} rad/s")


if __name__ == "__main__":
    main()
