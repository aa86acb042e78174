"""Firmware export: the exported C compiled strictly and with sanitizers, driven over drive logs
through its harness and compared with ``evstab replay``, ``evstab estimate --design`` and the
simulator's controller; the JSON round trip; the A2L through a2ltool; the CDFX against the JSON.

Tolerances (the issue's): float64 C within 1e-9 rad of evstab on sideslip and steer; float32
within 1e-4 rad. The yaw moment is held to "the same" as the steer: 1e-9 (1e-4) rad times the
front axle's yaw-moment gain 2 C_f l_f, i.e. the yaw moment of that much steer. In the controller
the yaw-moment row is ``N_z = (v2 - b21 delta) / b22``, so a steer difference reaches it multiplied
by exactly ``b21 / b22 = 2 C_f l_f``.
"""

import json
import shutil
import subprocess
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest

from evstab.controllers.schedule import ROWS, SpeedSchedule
from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
from evstab.plants.backend import CASADI
from evstab.plants.bicycle import lateral_coefficients
from evstab.plants.disturbances import Disturbances, Friction, default_wind
from evstab.plants.maneuvers import make_maneuver
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.cli import main
from evstab.toolkit.kernels.compiled import compiler
from evstab.toolkit.design.design_job import basic_design_document, load_design
from evstab.toolkit.design.record import design_points
from evstab.toolkit.estimation import design_filter
from evstab.toolkit.estimation.spec import NoiseSettings, estimation_noise
from evstab.toolkit.firmware import gains as gains_mod
from evstab.toolkit.ecu.step import INPUTS, OUTPUTS, EcuDesign, ecu_step
from evstab.toolkit.firmware.export import ecu_from_design, gain_set, render
from evstab.toolkit.firmware.replay import ecu_inputs, ecu_program
from evstab.toolkit.loop.simulator import simulate

CC = compiler()
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]
SANITIZE = ["-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer"]
TOL = {"float64": 1e-9, "float32": 1e-4}


def _commands_close(actual, desired, atol, shift):
    """``actual`` within ``atol`` of ``desired``, plus ``shift`` times the largest ``|desired|`` (a ramp of the
    law's authority a period apart: see the callers)."""
    actual, desired = np.asarray(actual, float), np.asarray(desired, float)
    bound = atol + shift * np.max(np.abs(desired))
    bad = np.flatnonzero(~(np.abs(actual - desired) <= bound))
    assert bad.size == 0, f"{bad.size} samples differ by more than {bound:g}, first at {bad[0]}: " \
                          f"{actual[bad[0]]:g} against {desired[bad[0]]:g}"


MU = 0.8


@pytest.fixture(scope="module")
def design_dir(tmp_path_factory):
    """A design folder with gains and noise away from the defaults (so calibration values travel)."""
    p = load_vehicle("compact-ev")
    noise = NoiseSettings(q_beta=2.1e-5, q_yaw_rate=0.05, q_d1=0.004, q_d2=0.03)
    filt = design_filter("dakf", p, noise, control=True)
    # dead bands low enough that the lane change below switches the law on and off (so activation,
    # blending and the authority limit are exercised), and away from the defaults
    ctl = TwoDofDesign(p.as_nominal(), k_beta=6.5, k_gamma=4.25, yaw_priority=2.0, yaw_rate_deadband=np.radians(0.5),
                       yaw_rate_deadband_per_speed=0.0, steer_authority=np.radians(6.0))
    doc = basic_design_document(p, filt, ctl, {"rate_hz": 5.0, "latency_s": 0.0, "hdop": 0.9, "satellites": 10},
                                "test fixture")
    out = tmp_path_factory.mktemp("design")
    (out / "design.json").write_text(json.dumps(doc, indent=2))
    return out


@pytest.fixture(scope="module")
def ecu(design_dir):
    return ecu_from_design(design_dir)[0]


@pytest.fixture(scope="module")
def closed_loop(ecu, tmp_path_factory):
    """The designed estimator and controller closing the loop in the simulator (two-track plant,
    lane change at 60 km/h on mu 0.8 with a side-wind gust and a 2 s GPS outage)."""
    p = load_vehicle("compact-ev")
    man = make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(3.0))
    res = simulate(p, "two-track", man, sensors=SensorConfig(gps_outages=((2.0, 4.0),)), seed=7,
                   controller="two-dof", design=ecu,
                   disturbances=Disturbances(wind=default_wind(p), friction=Friction(mu=MU)))
    path = tmp_path_factory.mktemp("logs") / "closed_loop.csv"
    res.write_csv(path)
    return res, path


@pytest.fixture(scope="module")
def fault_log(closed_loop, tmp_path_factory):
    """The closed-loop log with faults an ECU meets: course spikes, fixes with 3 satellites, bad HDOP,
    a stretch of standstill and creeping (hold branches, standstill update; gyro and accelerometer
    scaled to the lower speed, so the log stays a possible drive), the course a full turn on
    (past +pi), and actuator limit flags."""
    res, _ = closed_loop
    cols = {k: np.array(v, float) for k, v in res.log_columns().items() if not k.endswith("_true")}
    n = len(cols["t"])
    fix = np.flatnonzero(np.isfinite(cols["gps_course"]))
    cols["gps_course"][fix[5]] += 0.2  # a 11 deg spike
    cols["gps_course"][fix[12]] -= 0.5
    cols["gps_sats"][fix[20]] = 3.0  # unusable fix
    cols["gps_hdop"][fix[25]] = 8.0
    cols["gps_course"][fix[30:]] += 2 * np.pi  # the course after a full turn: past +pi, same direction
    rng = np.random.default_rng(11)
    cols["steer_limited_last"] = (rng.random(n) < 0.02).astype(float)
    cols["yaw_moment_limited_last"] = (rng.random(n) < 0.02).astype(float)
    k0, k1 = n // 2, n // 2 + 800
    slow = np.concatenate([np.zeros(400), np.linspace(0.0, 4.0, 400)])  # stop, then creep
    ratio = slow / cols["speed"][k0:k1]  # same path curvature at the lower speed: r ~ v, ay ~ v^2
    cols["yaw_rate"][k0:k1] = cols["yaw_rate"][k0:k1] * ratio + 0.002  # plus a gyro bias the standstill finds
    cols["ay"][k0:k1] *= ratio ** 2
    cols["speed"][k0:k1] = slow
    path = tmp_path_factory.mktemp("logs") / "faults.csv"
    from evstab.toolkit.logs.drivelog import write_log_csv
    write_log_csv(path, cols)
    return cols, path


def _run(cmd, **kw):
    out = subprocess.run(cmd, capture_output=True, text=True, **kw)
    assert out.returncode == 0, f"{cmd[0]} failed ({out.returncode}):\n{out.stderr[-3000:]}"
    return out


@pytest.fixture(scope="module", params=["float64", "float32"])
def firmware(request, design_dir, tmp_path_factory):
    """The exported C (one precision) built strictly with -O2 and again with the sanitizers."""
    if CC is None:
        pytest.skip("no C compiler on this machine")
    out = tmp_path_factory.mktemp("fw_" + request.param)
    assert main(["export", str(design_dir), "--format", "c", "--precision", request.param, "--out", str(out)]) == 0
    srcs = [str(out / "evstab_firmware.c"), str(out / "evstab_replay.c")]
    _run([CC, *STRICT, "-O2", "-o", str(out / "replay"), *srcs, "-lm"])
    _run([CC, *STRICT, *SANITIZE, "-o", str(out / "replay_san"), *srcs, "-lm"])
    return request.param, out


def _harness(binary, inputs_csv):
    res = _run([str(binary), str(inputs_csv)])
    assert res.stderr == ""  # sanitizers report here
    lines = res.stdout.splitlines()
    assert lines[0].split(",") == list(OUTPUTS)
    return np.loadtxt(lines[1:], delimiter=",", ndmin=2)


def _replay_cli(design_dir, log_path, tmp_path):
    out, inputs = tmp_path / "replay.csv", tmp_path / "inputs.csv"
    assert main(["replay", str(log_path), "--design", str(design_dir), "--mu", str(MU), "--out", str(out),
                 "--inputs-out", str(inputs)]) == 0
    data = np.genfromtxt(out, delimiter=",", names=True)
    return data, inputs


@needs_cc
@pytest.mark.parametrize("which", ["closed_loop", "fault_log"])
def test_exported_c_equals_replay_and_estimate(firmware, design_dir, ecu, which, request, tmp_path):
    precision, fw = firmware
    _, log_path = request.getfixturevalue(which)
    rep, inputs = _replay_cli(design_dir, log_path, tmp_path)
    est_path = tmp_path / "est.csv"
    assert main(["estimate", str(log_path), "--design", str(design_dir), "--out", str(est_path)]) == 0
    est = np.genfromtxt(est_path, delimiter=",", names=True)
    Y = _harness(fw / "replay", inputs)
    Y_san = _harness(fw / "replay_san", inputs)
    col = OUTPUTS.columns(Y)
    tol = TOL[precision]
    nz_tol = tol * 2 * ecu.controller.params.cornering_stiffness_front * ecu.controller.params.lf
    # float32 may cross a threshold of the law (activation, a dead band) a period before or after float64
    # (docs/firmware.md): the law's authority then ramps a period apart, by a blend step (dt / blend_time,
    # 1 %) of the law's command, at most of the run's largest command; float64 none
    shift = ecu.controller.dt / ecu.controller.blend_time if precision == "float32" else 0.0
    assert len(Y) == len(rep)
    np.testing.assert_allclose(col["beta"], est["beta"], rtol=0, atol=tol)
    np.testing.assert_allclose(col["beta"], rep["beta"], rtol=0, atol=tol)
    np.testing.assert_allclose(col["beta_telemetry"], est["beta_telemetry"], rtol=0, atol=tol)
    np.testing.assert_allclose(col["yaw_rate"], rep["yaw_rate"], rtol=0, atol=tol)
    _commands_close(col["steer_cmd"], rep["steer_cmd"], tol, shift)
    _commands_close(col["yaw_moment_cmd"], rep["yaw_moment_cmd"], nz_tol, shift)
    torque_tol = nz_tol * ecu.wheel_radius / ecu.track_rear  # T = N_z R_w / t_r
    _commands_close(col["torque_rr"], rep["torque_rr"], torque_tol, shift)
    _commands_close(col["torque_rl"], rep["torque_rl"], torque_tol, shift)
    np.testing.assert_array_equal(col["gps_used"], rep["gps_used"])
    # the sanitizer build computes the same numbers (no undefined behaviour changes a result)
    np.testing.assert_allclose(Y_san, Y, rtol=0, atol=tol)
    print(f"\n{precision} {which}: largest difference from the replay: sideslip "
          f"{np.max(np.abs(col['beta'] - rep['beta'])):.2g} rad, steer command "
          f"{np.max(np.abs(col['steer_cmd'] - rep['steer_cmd'])):.2g} rad, yaw-moment command "
          f"{np.max(np.abs(col['yaw_moment_cmd'] - rep['yaw_moment_cmd'])):.2g} N m")  # the README's table
    if which == "fault_log":  # the faults reached the filter: spikes gated, the 3-satellite fix dropped
        fixes = np.isfinite(np.genfromtxt(log_path, delimiter=",", names=True)["gps_course"])
        assert 0 < col["gps_used"].sum() < fixes.sum() - 2


@needs_cc
def test_exported_c_equals_the_simulators_controller(firmware, design_dir, ecu, closed_loop, tmp_path):
    """The C, fed the closed loop's sensor log, issues the commands the simulator's controller issued."""
    precision, fw = firmware
    res, log_path = closed_loop
    _, inputs = _replay_cli(design_dir, log_path, tmp_path)
    Y = _harness(fw / "replay", inputs)
    col = OUTPUTS.columns(Y)
    c = res.commands
    tol = TOL[precision]
    nz_tol = tol * 2 * ecu.controller.params.cornering_stiffness_front * ecu.controller.params.lf
    shift = ecu.controller.dt / ecu.controller.blend_time if precision == "float32" else 0.0  # as above
    np.testing.assert_allclose(col["beta"], c["beta_est"], rtol=0, atol=tol)
    _commands_close(col["steer_cmd"], c["steer_cmd"], tol, shift)
    _commands_close(col["yaw_moment_cmd"], c["yaw_moment_cmd"], nz_tol, shift)
    np.testing.assert_allclose(col["yaw_rate_ref"], c["yaw_rate_ref"], rtol=0, atol=tol)
    # the run exercised the controller: commands well above the tolerances, the motors hit their limit
    assert np.abs(c["yaw_moment_cmd"]).max() > 1000 and np.abs(c["steer_cmd"]).max() > 0.01
    assert c["yaw_moment_limited_last"].sum() > 0


def test_replay_compiled_equals_numpy_reference(ecu, fault_log):
    """casadi's generated C (the replay) against the plain numpy step, over the faulty stretch."""
    cols, _ = fault_log
    n = len(cols["t"])
    sl = slice(n // 2 - 300, n // 2 + 1200)  # standstill, creep and fixes
    U = ecu_inputs(cols, MU, wheel_radius=ecu.wheel_radius)[sl]
    Y_c = ecu_program(ecu).run(U)
    Y_np = ecu_program(ecu, "numpy").run(U)
    # same operations in the same order, casadi folds constants where numpy does not: 1e-12 relative
    scale = np.maximum(np.abs(Y_np).max(axis=0), 1e-6)
    assert np.all(np.abs(Y_c - Y_np).max(axis=0) <= 1e-12 * scale)


def test_the_replay_runs_the_guard_with_the_laws_authority():
    """The guard reads the law's authority and its last yaw-moment command (the vote, the two steer angles, the
    applied yaw moment), so the replay runs it on the whole state each sample, as ``evstab_step`` does. An ECU
    started 1.77 s into the ISO 3888-1 lane change at 100 km/h on mu 0.5 (compact-ev, its default ECU, an ECU
    reset at speed): its law acts, and the road-wheel angle leaves the driver's by more than the steer-agreement
    band while it does (which a guard that took the law for passive would have replaced, from 0.2 s on). The
    compiled replay equals the numpy step to 1e-12 of each output's scale (as above)."""
    from evstab.toolkit.loop.loop_ecu import loop_ecu
    p = load_vehicle("compact-ev")
    d = loop_ecu("two-dof", p).ecu
    res = simulate(p, "two-track", make_maneuver("iso3888-1", p, 100 / 3.6), seed=0, controller="two-dof", design=d,
                   disturbances=Disturbances(friction=Friction(mu=0.5)))
    U = ecu_inputs(res.log_columns(), d.controller.mu_max, wheel_radius=d.wheel_radius)[1770:3770]
    Y_c = ecu_program(d).run(U)
    Y_np = ecu_program(d, "numpy").run(U)
    scale = np.maximum(np.abs(Y_np).max(axis=0), 1e-6)
    assert np.all(np.abs(Y_c - Y_np).max(axis=0) <= 1e-12 * scale)
    y, g = OUTPUTS.columns(Y_np), INPUTS.columns(U)
    band = d.guard.steer_agree + d.guard.steer_agree_share * np.abs(g["steer"])
    acting = (y["active"] > 0) & (np.abs(g["steer_cmd_driver"] - g["steer"]) > band)
    assert acting.sum() > 100


def test_the_telemetry_sideslip_is_the_conditioned_estimate_and_the_law_never_reads_it(ecu, closed_loop):
    """``beta_telemetry`` (the second sideslip output, for logs and telemetry) against the filter's own
    conditioned output (``kalman.step`` with ``disturbance_chi2_on/full``, the output of ``evstab estimate``'s
    log filters, whose conditioning test_estimation checks against numpy's Gaussian conditioning) on the same
    ECU over the closed loop's sensor log; and the law's commands and every other output bit for bit the same
    whatever its calibration, so the control law is unchanged by construction."""
    res, _ = closed_loop
    cols = {k: np.asarray(v, float) for k, v in res.log_columns().items()}
    U = ecu_inputs(cols, MU, wheel_radius=ecu.wheel_radius)
    Y = ecu_program(ecu).run(U)
    other = replace(ecu, telemetry_chi2_on=20.0, telemetry_chi2_full=40.0)  # conditioned nearly throughout
    Y2 = ecu_program(other).run(U)
    k = OUTPUTS.index("beta_telemetry")
    rest = [i for i in range(OUTPUTS.size) if i != k]
    np.testing.assert_array_equal(Y2[:, rest], Y[:, rest])  # commands, beta, references: bit for bit
    col, col2 = OUTPUTS.columns(Y), OUTPUTS.columns(Y2)
    assert (ecu.telemetry_chi2_on, ecu.telemetry_chi2_full) == (0.5, 2.0)  # the defaults (TELEMETRY_CHI2)
    for d, c in ((ecu, col), (other, col2)):
        # the filter's own output conditioned at the telemetry's ends: its recursion is the same (the output
        # does not feed back and the replay's inputs are the log's), so its beta is beta_telemetry: the same
        # operations on the state the step packed; 0 difference measured, 1e-15 rad leaves a compiler's
        # contraction room
        noise = replace(d.filter.noise, disturbance_chi2_on=d.telemetry_chi2_on,
                        disturbance_chi2_full=d.telemetry_chi2_full)
        cond = replace(d, filter=replace(d.filter, noise=noise))
        Y3 = OUTPUTS.columns(ecu_program(cond).run(U))
        np.testing.assert_allclose(Y3["beta_telemetry"], c["beta_telemetry"], rtol=0, atol=1e-15)
        np.testing.assert_allclose(Y3["beta"], c["beta_telemetry"], rtol=0, atol=1e-15)
    # the output is not the law's estimate: the disturbances carried course noise the conditioning drops
    # (0.0022 rad at most with the defaults, 0.0026 conditioned nearly throughout, measured)
    gap = np.abs(col["beta_telemetry"] - col["beta"])
    assert gap.max() > 1e-4 and np.abs(col2["beta_telemetry"] - col["beta"]).max() > gap.max()


def test_a_replay_at_another_rate_lifts_the_band_on_the_period(ecu):
    """The guard uses a period only within half of the nominal one either side (GuardSettings.dt_band): a replay
    of a log recorded at 200 Hz through a 1 kHz design runs with the log's periods (the band lifted), a 1 kHz
    log with 30 % jitter keeps the band (and the C's behaviour)."""
    from evstab.toolkit.firmware.replay import for_log_periods
    assert ecu.guard.dt_band == 0.5 and ecu.filter.dt_nominal == 1e-3
    rng = np.random.default_rng(3)
    for dt, lifted in ((np.full(50, 5e-3), True), (1e-3 * (1 + 0.3 * rng.uniform(-1, 1, 50)), False),
                       (np.full(50, 1.5e-3 * (1 + 1e-9)), True)):
        U = INPUTS.zeros(50)
        INPUTS.columns(U)["dt"][:] = dt
        d = for_log_periods(ecu, U)
        assert (d.guard.dt_band is None) == lifted
        assert replace(d, guard=ecu.guard) == ecu  # nothing else changes


def test_gain_set_round_trips_exactly(design_dir, ecu):
    doc = gain_set(design_dir, "cmd")
    text = gains_mod.dumps(doc)
    d, prov, gps = gains_mod.load_gains(json.loads(text))
    assert d == ecu  # every field of filter, controller, schedule and split, bit for bit
    assert gains_mod.dumps(gains_mod.gains_document(d, prov, gps)) == text
    assert doc["signals"]["inputs"][INPUTS.index("gps_course")]["unit"] == "rad"
    assert doc["controller"]["beta_error_max"] is None  # unlimited, written as null (JSON has no inf)
    cal = {c["name"]: c["value"] for c in doc["calibration"]}
    assert cal["k_beta"] == 6.5 and cal["q_d2"] == 0.03 and cal["torque_max"] == ecu.torque_max
    # each calibration scalar once in the file: the settings sections leave them to the calibration list
    assert "k_beta" not in doc["controller"] and "q_d2" not in doc["estimator"]["noise"]
    assert text.count('"k_beta"') == 1 and text.count('"k_gamma"') == 1


def test_a_gain_set_of_format_1_still_loads(design_dir, ecu):
    """Format 1 wrote each calibration scalar twice, in its section and in the calibration list; the list is
    authoritative, so a section's stale copy changes nothing."""
    doc = gain_set(design_dir)
    doc["format"] = "evstab-gains/1"
    doc["controller"]["k_beta"] = 1.0  # a stale copy: the calibration list's 6.5 wins
    doc["torque_split"]["torque_max_nm"] = 1.0
    assert gains_mod.load_gains(doc)[0] == ecu


def test_the_telemetry_calibration_is_checked_and_may_be_absent(design_dir, ecu):
    """beta_telemetry's smoothstep needs its upper end above its lower: refused at load, naming both; a gain set
    of an ECU without the output (no telemetry entries) loads with the defaults."""
    doc = gain_set(design_dir)
    cal = {c["name"]: c for c in doc["calibration"]}
    cal["telemetry_chi2_full"]["value"] = 0.5  # equal to telemetry_chi2_on: inside both A2L ranges, not a step
    with pytest.raises(gains_mod.GainSetError, match="telemetry_chi2_full.*telemetry_chi2_on"):
        gains_mod.load_gains(doc)
    doc = gain_set(design_dir)
    doc["calibration"] = [c for c in doc["calibration"] if not c["name"].startswith("telemetry_")]
    assert gains_mod.load_gains(doc)[0] == ecu


def test_an_edited_calibration_value_reaches_the_c(design_dir):
    doc = gain_set(design_dir)
    for c in doc["calibration"]:
        if c["name"] == "k_gamma":
            c["value"] = 3.75
    d, _, _ = gains_mod.load_gains(doc)
    assert d.controller.k_gamma == 3.75
    src = render(doc, ["c"], "float64")["evstab_firmware.c"].decode()
    assert "evstab_cal_k_gamma = 3.75;" in src


def test_gain_set_errors_name_the_field(tmp_path, design_dir):
    doc = gain_set(design_dir)
    del doc["schedule"]["axis"]
    with pytest.raises(gains_mod.GainSetError, match="field 'schedule'.*'axis'"):
        gains_mod.load_gains(doc)
    doc = gain_set(design_dir)
    doc["calibration"] = [c for c in doc["calibration"] if c["name"] != "gate"]
    with pytest.raises(gains_mod.GainSetError, match="field 'calibration'.*gate"):
        gains_mod.load_gains(doc)
    # a value outside the limits the A2L declares is refused (k_beta: 0.01 to 100 rad/s); at the limit it loads
    for value, ok in ((100.0, True), (100.5, False), (0.005, False)):
        doc = gain_set(design_dir)
        next(c for c in doc["calibration"] if c["name"] == "k_beta")["value"] = value
        if ok:
            assert gains_mod.load_gains(doc)[0].controller.k_beta == value
        else:
            with pytest.raises(gains_mod.GainSetError, match=r"field 'calibration'.*'k_beta' is .*outside its limits"):
                gains_mod.load_gains(doc)
    bad = tmp_path / "g.json"
    bad.write_text('{"format": "other"}')
    with pytest.raises(gains_mod.GainSetError, match=f"{bad}.*'format'"):
        gains_mod.load_gains(bad)


def test_a2l_parses_and_its_addresses_update_from_the_elf(design_dir, tmp_path):
    a2ltool = shutil.which("a2ltool")
    if a2ltool is None:
        pytest.skip("a2ltool (test extra) is not installed")
    if CC is None:
        pytest.skip("no C compiler on this machine")
    assert main(["export", str(design_dir), "--out", str(tmp_path), "--format", "all"]) == 0
    a2l = tmp_path / "evstab_firmware.a2l"
    res = _run([a2ltool, str(a2l), "--strict", "--check"])
    assert "No problems found" in res.stdout + res.stderr
    # the ECU project's step: link, then fill the A2L addresses from the ELF's debug information
    _run([CC, *STRICT, "-O2", "-g", "-o", str(tmp_path / "ecu"), str(tmp_path / "evstab_firmware.c"),
          str(tmp_path / "evstab_replay.c"), "-lm"])
    _run([a2ltool, str(a2l), "--elffile", str(tmp_path / "ecu"), "--update", "ADDRESSES", "--update-mode", "STRICT",
          "-o", str(tmp_path / "updated.a2l")])
    text = (tmp_path / "updated.a2l").read_text()
    doc = json.loads((tmp_path / "evstab_gains.json").read_text())
    n_objects = len(doc["calibration"]) + 1 + len(ROWS)
    assert text.count("/begin CHARACTERISTIC") + text.count("/begin AXIS_PTS") == n_objects
    assert " 0x0 " not in text  # every object got its address
    # the MEASUREMENT objects (every output, the watched supervisor state) sit where the ELF's symbol
    # table puts the harness's evstab_out / evstab_st plus the entry's offset (8 bytes per float64)
    import re
    from evstab.toolkit.firmware.asam import MEASURED_STATE, measurements
    from evstab.toolkit.firmware.export import ecu_from_design
    from evstab.toolkit.ecu.step import OUTPUTS
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("no nm (binutils)")
    sym = {line.split()[-1]: int(line.split()[0], 16) for line in _run([nm, str(tmp_path / "ecu")]).stdout.splitlines()
           if len(line.split()) == 3}
    got = dict(re.findall(r"/begin MEASUREMENT (\w+) .*?ECU_ADDRESS (0x[0-9A-Fa-f]+)", text, flags=re.S))
    ecu, _ = ecu_from_design(design_dir)
    meas = measurements(ecu)
    assert len(got) == len(meas) == len(OUTPUTS) + len(MEASURED_STATE)
    for i, name in enumerate(OUTPUTS):
        assert int(got[f"out_{name}"], 16) == sym["evstab_out"] + 8 * i
    for m in meas[len(OUTPUTS):]:
        assert int(got[m["name"]], 16) == sym["evstab_st"] + 8 * m["index"]


def test_a2l_and_c_name_the_same_objects(design_dir):
    doc = gain_set(design_dir)
    files = render(doc, ["c", "a2l"], "float32")
    a2l, src = files["evstab_firmware.a2l"].decode(), files["evstab_firmware.c"].decode()
    symbols = [c["symbol"] for c in doc["calibration"]] + [doc["schedule"]["axis"]["symbol"]] + \
        [r["symbol"] for r in doc["schedule"]["rows"]]
    for s in symbols:
        assert f"EVSTAB_CALIBRATION evstab_real {s}" in src
        assert f'SYMBOL_LINK "{s}" 0' in a2l
    assert a2l.count(" 1 FLOAT32_IEEE ") == 3 and "FLOAT64_IEEE INDEX_INCR" not in a2l


def test_cdfx_is_well_formed_and_carries_the_json_values(design_dir):
    doc = gain_set(design_dir)
    root = ET.fromstring(render(doc, ["cdfx"], "float64")["evstab_firmware.cdfx"])
    values = {}
    for inst in root.iter("SW-INSTANCE"):
        name = inst.findtext("SHORT-NAME")
        values[name] = (inst.findtext("CATEGORY"), [float(v.text) for v in inst.find("SW-VALUE-CONT/SW-VALUES-PHYS")])
    for c in doc["calibration"]:
        assert values.pop(c["symbol"]) == ("VALUE", [c["value"]])
    ax = doc["schedule"]["axis"]
    assert values.pop(ax["symbol"]) == ("COM_AXIS", ax["values"])
    for r in doc["schedule"]["rows"]:
        assert values.pop(r["symbol"]) == ("CURVE", r["values"])
    assert values == {}


@needs_cc
def test_firmware_object_has_no_mutable_globals_heap_or_unbounded_stack(design_dir, tmp_path):
    assert main(["export", str(design_dir), "--format", "c", "--out", str(tmp_path)]) == 0
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("no nm (binutils)")
    src = tmp_path / "evstab_firmware.c"
    doc = gain_set(design_dir)
    calibration = {c["symbol"] for c in doc["calibration"]} | {doc["schedule"]["axis"]["symbol"]} | \
        {r["symbol"] for r in doc["schedule"]["rows"]}

    def symbols(*flags):
        obj = tmp_path / "fw.o"
        _run([CC, *STRICT, "-O2", "-fstack-usage", *flags, "-c", "-o", str(obj), str(src)], cwd=tmp_path)
        return [line.split() for line in _run([nm, str(obj)]).stdout.splitlines()]

    # default: calibration data is `static const volatile` (kept in memory for the A2L); gcc puts
    # volatile objects in .data, but nothing else is there, and the program cannot write them (const)
    syms = symbols()
    writable = {s[-1] for s in syms if s[-2] in "BbDdGgSs"}
    assert writable <= calibration, writable - calibration
    assert not {s[-1] for s in syms if s[-2] in "BbSs"}  # no .bss at all: no zero-initialised state
    # as plain `static const` (folded in) the object has no writable data at all
    syms = symbols('-DEVSTAB_CALIBRATION=static const')
    assert not {s[-1] for s in syms if s[-2] in "BbDdGgSs"}
    undefined = {s[-1] for s in syms if s[-2] == "U"}
    libm = {"memcpy", "fmax", "fmin", "fabs", "sqrt", "atan2", "sin", "cos", "sincos", "exp", "pow"}
    assert undefined <= libm, undefined - libm  # no malloc/free, no I/O
    usage = (tmp_path / "fw.su").read_text().splitlines()
    assert usage and all(line.endswith("static") for line in usage)  # fixed frame sizes: no VLA, no alloca
    # no recursion: evstab_step calls the segment lookup, the two tables' interpolations and the two
    # cores, which call only libm and read data
    text = src.read_text()
    for fn in ("int evstab_segment", "void evstab_transition_rows", "void evstab_schedule_rows", "void evstab_ecu_fix",
               "void evstab_ecu_nofix", "void evstab_ecu_nofix_moving"):
        body = text[text.index(f"static {fn}("):]
        body = body[:body.index("\n}\n")]
        assert "evstab_" not in body.split("{", 1)[1].replace("evstab_real", "").replace("evstab_cal_", "") \
            .replace("evstab_sched_", "").replace("evstab_transition[", "").replace("evstab_input_t", "") \
            .replace("evstab_output_t", "")


def test_schedule_closed_form_errors():
    """a11, a22, b11 are linear in 1/v and a21, b21, b22 constant: the table is exact. a12 = -1 + c x^2:
    linear interpolation of a quadratic misses by c h^2 / 4 at each segment's midpoint, exactly."""
    p = load_vehicle("compact-ev").as_nominal()
    s = SpeedSchedule.build(p)
    x = np.asarray(s.inv_speed)
    mid = 0.5 * (x[1:] + x[:-1])
    got = np.array(s.values(1.0 / mid))
    exact = np.array([lateral_coefficients(p, 1.0 / m) for m in mid]).T
    for r in (0, 2, 3, 4, 5, 6):
        np.testing.assert_allclose(got[r], exact[r], rtol=1e-13)  # rounding of the lookup only
    c = -2.0 * (p.cornering_stiffness_front * p.lf - p.cornering_stiffness_rear * p.lr) / p.mass
    np.testing.assert_allclose(got[1] - exact[1], c * np.diff(x) ** 2 / 4, rtol=1e-6)
    err = s.max_error(p)
    assert max(err.values()) < 4e-3  # the documented 0.4 % bound of the 32-point geometric grid


def test_schedule_lookup_equals_the_symbolic_hat_sum():
    import casadi as ca
    s = SpeedSchedule.build(load_vehicle("micro-ev").as_nominal())
    v = ca.SX.sym("v")
    f = ca.Function("f", [v], [ca.vertcat(*s.values(v, CASADI))])
    for speed in (0.5, 2.0, 2.7, 11.3, s.speeds[7], 69.0, 70.0, 120.0):
        np.testing.assert_allclose(np.array(f(speed)).ravel(), np.array(s.values(speed)), rtol=1e-14, atol=1e-14)


def test_ecu_signs_follow_iso_8855(ecu):
    """A left steer asks for a left (positive) yaw rate; a positive yaw moment command speeds the
    right rear wheel and brakes the left one by N_z R_w / t_r each; a positive gyro reading makes a
    positive yaw-rate estimate."""
    u = np.zeros(len(INPUTS))
    g = dict(zip(INPUTS, range(len(INPUTS))))
    u[g["dt"]], u[g["speed"]], u[g["gps_hdop"]], u[g["gps_sats"]], u[g["mu"]] = 1e-3, 20.0, 1.0, 10, 1.0
    u[g["wheel_speed_rl"]] = u[g["wheel_speed_rr"]] = 20.0 / ecu.wheel_radius  # rolling, no slip
    # a steady turn: the lateral acceleration v r that goes with the yaw rate (a gyro that holds its value
    # while the accelerometer disagrees is stuck for the input guard)
    u[g["yaw_rate"]], u[g["ay"]] = 0.05, 20.0 * 0.05
    z = ecu.initial_state()
    for _ in range(50):
        z, y = ecu_step(ecu, z, u, ecu.schedule_inputs(u[g["speed"]]))
    assert dict(zip(OUTPUTS, y))["yaw_rate"] > 0
    # the driver steers left and the car does not turn (understeer): the law acts, turning left
    # (the steer applied over 10 ms: an instant 1 deg step would be 17 rad/s, which the input guard takes for
    # a fault; toolkit.ecu.guard)
    u[g["yaw_rate"]], u[g["ay"]] = 0.0, 0.0
    for k in range(300):
        u[g["steer_cmd_driver"]] = np.radians(1.0) * min((k + 1) / 10, 1.0)
        z, y = ecu_step(ecu, z, u, ecu.schedule_inputs(u[g["speed"]]))
    assert dict(zip(OUTPUTS, y))["fault_word"] == 0
    out = dict(zip(OUTPUTS, y))
    assert out["yaw_rate_ref"] > 0 and out["active"] == 1.0
    nz = out["yaw_moment_cmd"]
    assert nz > 0 and out["steer_cmd"] >= u[g["steer_cmd_driver"]]
    assert out["torque_rr"] == pytest.approx(-out["torque_rl"])
    assert out["torque_rr"] == pytest.approx(np.clip(nz * ecu.wheel_radius / ecu.track_rear, -ecu.torque_max,
                                                     ecu.torque_max), rel=1e-12)


def test_export_refuses_bad_input_and_writes_nothing(tmp_path, capsys, design_dir):
    out = tmp_path / "out"
    assert main(["export", str(tmp_path / "missing"), "--out", str(out)]) == 2
    assert "missing" in capsys.readouterr().err and not out.exists()
    doc = json.loads((design_dir / "design.json").read_text())
    doc["estimator"]["method"] = "lob"
    bad = tmp_path / "lob"
    bad.mkdir()
    (bad / "design.json").write_text(json.dumps(doc))
    assert main(["export", str(bad), "--out", str(out)]) == 2
    assert "lob" in capsys.readouterr().err and not out.exists()
    assert main(["estimate", "x.csv", "--vehicle", "compact-ev", "--design", str(design_dir), "--out",
                 str(out / "e.csv")]) == 2
    assert "not both" in capsys.readouterr().err


def test_ecu_design_rejects_what_firmware_cannot_run():
    p = load_vehicle("compact-ev").as_nominal()
    with pytest.raises(ValueError, match="Kalman-filter methods"):
        EcuDesign.from_designs(design_filter("lob", p), TwoDofDesign(p))
    # the kinematic sideslip path runs on the ECU too: its state is part of the ECU's
    kin = EcuDesign.from_designs(design_filter("dakf", p, control=True), TwoDofDesign(p))  # the default
    plain = EcuDesign.from_designs(design_filter("dakf", p, control=True, kinematic=False), TwoDofDesign(p))
    assert kin.n_state == plain.n_state + 4 and kin.filter.transition.a_entries
    with pytest.raises(ValueError, match="no kinematic sideslip path"):
        design_filter("kf-bias", p, control=True, kinematic=True)


def _design_dirs(tmp_path, p, filters: dict) -> dict:
    """A design folder per filter design (name -> folder), with the default controller and GPS."""
    ctl = TwoDofDesign(p.as_nominal())
    gps = {"rate_hz": 5.0, "latency_s": 0.0, "hdop": 0.9, "satellites": 10}
    dirs = {}
    for name, filt in filters.items():
        dirs[name] = tmp_path / name
        dirs[name].mkdir()
        (dirs[name] / "design.json").write_text(json.dumps(basic_design_document(p, filt, ctl, gps, "test"), indent=2))
    return dirs


def _c_and_other_replay(dirs: dict, name: str, other: str, res, tmp_path) -> tuple[dict, dict]:
    """Write the drive ``res`` as a log, check ``dirs[name]``'s exported C against its replay
    (:func:`_c_equals_replay`) and replay ``dirs[other]`` over the same log; returns both replays."""
    log_path = tmp_path / "drive.csv"
    res.write_csv(log_path)
    rep = _c_equals_replay(dirs[name], log_path, tmp_path)
    out = tmp_path / f"{other}_replay"
    out.mkdir()
    return rep, _replay_cli(dirs[other], log_path, out)[0]


def _c_equals_replay(design_dir, log_path, tmp_path) -> dict:
    """Export ``design_dir``'s C (float64), run it over ``log_path`` and compare it with the replay
    output by output; returns the replay."""
    out = tmp_path / "fw"
    assert main(["export", str(design_dir), "--format", "c", "--out", str(out)]) == 0
    _run([CC, *STRICT, "-O2", "-o", str(out / "replay"), str(out / "evstab_firmware.c"),
          str(out / "evstab_replay.c"), "-lm"])
    rep, inputs = _replay_cli(design_dir, log_path, tmp_path)
    Y = _harness(out / "replay", inputs)
    for i, name in enumerate(OUTPUTS):
        np.testing.assert_allclose(Y[:, i], rep[name], rtol=0, atol=TOL["float64"])
    return rep


@needs_cc
def test_an_ecu_with_the_adaptive_noise_exports_c_equal_to_its_replay(closed_loop, tmp_path):
    """The estimation noise in the ECU (a noise file fitted to a log and given to `evstab design --noise`
    brings it): the adaptive scale is filter state, the disturbances' initial spread is the
    noise's, and both reach the C. Compared with the replay over the closed-loop log (float64), and the
    scale changes the estimate (else the test would not see it travel)."""
    p = load_vehicle("compact-ev")
    dirs = _design_dirs(tmp_path, p, {
        "adaptive": design_filter("dakf", p, estimation_noise(), control=True),
        "fixed": design_filter("dakf", p, replace(estimation_noise(), adapt_rate=0.0), control=True)})
    _, log_path = closed_loop
    rep = _c_equals_replay(dirs["adaptive"], log_path, tmp_path)
    other = tmp_path / "fixed_replay"
    other.mkdir()
    fixed, _ = _replay_cli(dirs["fixed"], log_path, other)
    assert np.abs(fixed["beta"] - rep["beta"]).max() > 1e-5  # rad: the scale moved the estimate


@needs_cc
def test_an_ecu_with_the_kinematic_path_exports_c_equal_to_its_replay(tmp_path):
    """The kinematic sideslip path in the ECU (`kinematic` in design.json): its state and the tabulated
    model row it compares the accelerometer with reach the C, equal to the replay (float64) over the
    Vanagon's slide on mu 0.5 (studies.estimation_mb: to 21 deg of sideslip and back), where the
    path holds the estimate that the linear model alone loses."""
    from evstab.studies.estimation_mb import drives
    p = load_vehicle("commonroad-3")
    dirs = _design_dirs(tmp_path, p, {"kinematic": design_filter("dakf", p, control=True),
                                      "plain": design_filter("dakf", p, control=True, kinematic=False)})
    assert json.loads((dirs["kinematic"] / "design.json").read_text())["estimator"]["kinematic"] is True
    assert load_design(dirs["kinematic"]).filter.kinematic and not load_design(dirs["plain"]).filter.kinematic
    name, man, mu, sens, _ = drives(p, 3)[-1]
    assert name.startswith("slide")
    res = simulate(p, "commonroad-mb:3", man, disturbances=Disturbances(friction=Friction(mu=mu)), sensors=sens,
                   seed=3)
    rep, plain = _c_and_other_replay(dirs, "kinematic", "plain", res, tmp_path)
    truth = np.asarray(res.truth["beta"])
    assert np.abs(truth).max() > np.radians(15.0)  # the car slid
    sel = np.asarray(res.t) >= 1.0
    err = {k: np.degrees(np.sqrt(np.mean((r["beta"][sel] - truth[sel]) ** 2))) for k, r in (("kin", rep),
                                                                                             ("plain", plain))}
    # measured: 0.32 deg RMS with the path against 12.2 deg without; the issue asks <= 1 deg at the limit
    assert err["kin"] < 1.0 < 5.0 < err["plain"], err


@needs_cc
def test_an_amrkf_ecu_exports_c_equal_to_its_replay(tmp_path):
    """amrkf in the ECU: its residual prediction and the innovations' correlation state reach the C,
    equal to the replay (float64) over a lane change, the ECU designed from the +40 % stiffness file.
    The correlation threshold is lowered to 0 here so that the prediction acts (at the default, 0.6,
    the ECU's innovations on this log are too white for it and amrkf is dakf)."""
    from evstab.studies.estimation_mb import wrong
    p = load_vehicle("compact-ev")
    amr = design_filter("amrkf", wrong(p), control=True)
    amr = replace(amr, noise=replace(amr.noise, residual_corr_min=0.0))
    dirs = _design_dirs(tmp_path, wrong(p), {"amrkf": amr, "dakf": design_filter("dakf", wrong(p), control=True)})
    assert load_design(dirs["amrkf"]).filter.noise.residual_corr_min == 0.0
    res = simulate(p, "two-track", make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(4.0)), seed=2)
    rep, plain = _c_and_other_replay(dirs, "amrkf", "dakf", res, tmp_path)
    assert np.abs(rep["beta"] - plain["beta"]).max() > 1e-5  # rad: the prediction acted (measured 2.1e-4)


def test_replay_and_estimate_refuse_bad_input_and_write_nothing(tmp_path, capsys, design_dir, closed_loop):
    _, log = closed_loop
    out = tmp_path / "out.csv"
    assert main(["replay", str(log), "--design", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    assert "nowhere" in capsys.readouterr().err and not out.exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("t,speed,steer,yaw_rate,gps_course\n0,10,0,0,\n0.001,10,zero,0,\n")
    for cmd in (["replay", str(bad), "--design", str(design_dir), "--out", str(out)],
                ["estimate", str(bad), "--design", str(design_dir), "--out", str(out)]):
        assert main(cmd) == 2
        err = capsys.readouterr().err
        assert "bad.csv" in err and "steer" in err and "3" in err  # file, column, line
        assert not out.exists() and not list(tmp_path.glob(".out.csv*"))


@needs_cc
def test_a_real_design_folder_exports_and_its_c_equals_the_replay(quick_design_dir, closed_loop, tmp_path):
    """The whole flow on what `evstab design --quick` wrote (tuned gains and noise): export every format,
    build the C strictly, replay the closed-loop log both ways."""
    out = tmp_path / "fw"
    assert main(["export", str(quick_design_dir), "--out", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    assert names == {"evstab_firmware.h", "evstab_firmware.c", "evstab_replay.c", "evstab_gains.json",
                     "evstab_firmware.a2l", "evstab_firmware.cdfx"}
    doc = json.loads((out / "evstab_gains.json").read_text())
    tuned = design_points(json.loads((quick_design_dir / "design.json").read_text()))["tuned"]
    cal = {c["name"]: c["value"] for c in doc["calibration"]}
    assert cal["k_beta"] == tuned["k_beta"] and cal["q_d2"] == tuned["q_d2"]  # the tuned design travels
    _run([CC, *STRICT, "-O2", "-o", str(out / "replay"), str(out / "evstab_firmware.c"),
          str(out / "evstab_replay.c"), "-lm"])
    _, log_path = closed_loop
    rep, inputs = _replay_cli(quick_design_dir, log_path, tmp_path)
    Y = _harness(out / "replay", inputs)
    for i, name in enumerate(OUTPUTS):
        np.testing.assert_allclose(Y[:, i], rep[name], rtol=0, atol=TOL["float64"])


def test_simulate_with_a_design_folder_runs_its_ecu_in_the_loop(design_dir, ecu, tmp_path, capsys):
    """``evstab simulate --design DIR`` closes the loop with the folder's ECU: the same run as the
    simulator given that ECU, and not the default design's."""
    from evstab.toolkit.logs.channels import read_log
    out = tmp_path / "run.csv"
    args = ["simulate", "--vehicle", "compact-ev", "--maneuver", "step-steer", "--speed", "60", "--amplitude", "2",
            "--out", str(out)]
    assert main(args + ["--design", str(design_dir)]) == 0
    log = read_log(out)
    p = load_vehicle("compact-ev")
    man = make_maneuver("step-steer", p, 60 / 3.6, np.radians(2.0))
    res = simulate(p, "two-track", man, controller="two-dof", design=ecu)
    np.testing.assert_allclose(log["yaw_moment_cmd"], res.commands["yaw_moment_cmd"], rtol=1e-12, atol=1e-9)  # CSV
    default = simulate(p, "two-track", man, controller="two-dof")
    assert np.max(np.abs(default.commands["yaw_moment_cmd"] - res.commands["yaw_moment_cmd"])) > 10.0  # N m
    assert main(args + ["--design", str(design_dir), "--estimator", "kf"]) == 2
    assert "--estimator" in capsys.readouterr().err
    assert main(args + ["--estimator", "kf"]) == 2  # a filter in the loop needs --controller


@needs_cc
def test_the_c_refuses_fast_math_and_promotes_no_float(firmware, tmp_path):
    """The input guard finds NaN and Inf by comparisons that -ffast-math and -ffinite-math-only let the compiler
    assume away: the header refuses them by name. The float32 build promotes nothing to double."""
    precision, fw = firmware
    src = str(fw / "evstab_firmware.c")
    for flag in ("-ffast-math", "-ffinite-math-only"):
        res = subprocess.run([CC, *STRICT, flag, "-c", src, "-o", str(tmp_path / "x.o")], capture_output=True, text=True)
        assert res.returncode != 0 and "do not compile with -ffast-math" in res.stderr
    if precision == "float32":
        _run([CC, *STRICT, "-Wdouble-promotion", "-c", src, "-o", str(tmp_path / "y.o")])


LONG_DRIVE_C = r"""
/* An hour in circles at 1 kHz: the ECU step fed a steady circle with seeded noise, the driver's steer
   swinging +-0.05 rad at 0.25 Hz about the circle's (the law switches in and out); every 1000th step's
   sideslip, steer and yaw-moment commands printed. Args: seconds v R steer beta seed wheel_radius */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "evstab_firmware.h"
static unsigned long long state;
static double unif(void) { state = state * 6364136223846793005ULL + 1442695040888963407ULL;
    return (double)(state >> 11) * (1.0 / 9007199254740992.0); }
static double gauss(void) { double s = 0.0; int i; for (i = 0; i < 12; i++) { s += unif(); } return s - 6.0; }
int main(int argc, char **argv)
{
    static evstab_state_t s;
    evstab_input_t in;
    evstab_output_t out;
    double v = atof(argv[2]), R = atof(argv[3]), steer = atof(argv[4]), beta = atof(argv[5]), rw = atof(argv[7]);
    long k, n = (long)(atof(argv[1]) * 1000.0 + 0.5);
    (void)argc;
    state = (unsigned long long)atol(argv[6]);
    evstab_init(&s);
    for (k = 0; k < n; k++) {
        double t = k * 1e-3, r = v / R;
        in.dt = (evstab_real)1e-3;
        in.speed = (evstab_real)(v + 0.02 * gauss());
        in.steer = (evstab_real)(steer + 1e-4 * gauss());
        in.yaw_rate = (evstab_real)(r + 1.5e-3 * gauss());
        in.ay = (evstab_real)(v * r + 0.05 * gauss());
        in.gps_valid = (k % 200) == 0;
        /* the course as a receiver gives it: wrapped (the step wraps its innovation either way) */
        in.gps_course = (evstab_real)(in.gps_valid ? remainder(r * t + beta + 0.0035 * gauss(), 2.0 * M_PI) : 0.0);
        in.gps_speed = (evstab_real)v;
        in.gps_hdop = (evstab_real)0.9;
        in.gps_sats = 10;
        in.steer_cmd_driver = (evstab_real)(steer + 0.05 * sin(2.0 * M_PI * 0.25 * t));
        in.yaw_moment_applied = (evstab_real)0.0;
        in.steer_limited = 0;
        in.yaw_moment_limited = 0;
        in.mu = (evstab_real)10.0;
        in.wheel_speed_rl = (evstab_real)(v / rw);
        in.wheel_speed_rr = (evstab_real)(v / rw);
        evstab_step(&s, &in, &out);
        if (k % 1000 == 999) {
            printf("%.9e %.9e %.9e %.9e\n", (double)out.beta, (double)out.steer_cmd, (double)out.yaw_moment_cmd,
                   (double)out.yaw);
        }
    }
    return 0;
}
"""


@needs_cc
def test_float32_holds_float64_over_an_hour_in_circles(design_dir, ecu, tmp_path):
    """One hour at 60 km/h on a 100 m circle (600 rad of heading), float32 against float64 of the same export.

    Bounds: the sideslip within 1e-4 rad of float64 all hour (measured 1.3e-5 rad; a heading kept continuous
    in float32 loses its resolution as it grows and the difference then reaches 0.17 rad); the heading output
    wrapped to (-pi, pi]. The commands are those of a law with thresholds (activation, dead bands): where
    float32 and float64 cross one a period apart they differ until both have switched; the share of the
    hour's sampled seconds where they differ by more than 1 mrad of steer or 10 N m is at most 3 % (measured
    0.4 % with this design, 1.5 % with compact-ev's default one: twice the larger), and the first minute's
    commands agree within 1 N m (measured 0.10 N m) and, in 95 % of its samples, within 1e-6 rad of steer
    (measured: 58 of 60 within 4.4e-7 rad; the other two 2.3e-5 and 3.1e-5 rad, where the law switches a
    period apart, below one blend step of the steer authority, 1.05e-3 rad)."""
    p = ecu.controller.params
    v, radius = 60 / 3.6, 100.0
    a11, a12, a21, a22, b11, b21, b22 = lateral_coefficients(p, v)
    beta, steer = np.linalg.solve([[a11, b11], [a21, b21]], [-a12 * v / radius, -a22 * v / radius])
    rows = {}
    for precision in ("float32", "float64"):
        out = tmp_path / precision
        assert main(["export", str(design_dir), "--format", "c", "--precision", precision, "--out", str(out)]) == 0
        (out / "drive.c").write_text(LONG_DRIVE_C)
        _run([CC, "-std=gnu99", "-O2", "-o", str(out / "drive"), str(out / "drive.c"), str(out / "evstab_firmware.c"),
              "-lm"], cwd=out)
        text = _run([str(out / "drive"), "3600", repr(v), repr(radius), repr(float(steer)), repr(float(beta)), "7",
                     repr(ecu.wheel_radius)]).stdout
        rows[precision] = np.loadtxt(text.splitlines())
    a, b = rows["float32"], rows["float64"]
    assert len(a) == 3600 and np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    assert np.abs(a[:, 0] - b[:, 0]).max() < 1e-4
    assert np.all(np.abs(a[:, 3]) <= np.pi + 1e-6)
    ds, dn = np.abs(a[:, 1] - b[:, 1]), np.abs(a[:, 2] - b[:, 2])
    assert np.mean((ds > 1e-3) | (dn > 10.0)) <= 0.03
    # the first minute: within 1e-6 rad of steer but where an activation threshold is crossed a period apart,
    # which moves the blend weight by one step (dt / blend_time) of at most the steer authority
    step = ecu.controller.dt / ecu.controller.blend_time * ecu.controller.steer_authority
    assert np.mean(ds[:60] < 1e-6) >= 0.95 and ds[:60].max() <= step
    assert dn[:60].max() < 1.0
    assert np.abs(b[:, 2]).max() > 100.0  # the law acted during the hour (the commands were exercised)
