"""The ECU's input guard (toolkit.ecu.guard): bad samples replaced and counted, persistent faults named
in the fault word, the law's authority ramped out and back, the filter restarted; on clean inputs nothing
changes."""

from __future__ import annotations

import numpy as np
import pytest

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
from evstab.plants.backend import NUMPY
from evstab.toolkit.estimation import design_filter
from evstab.toolkit.ecu import guard as gm
from evstab.toolkit.ecu.step import INPUTS, OUTPUTS, EcuDesign, ecu_step

DT = 1e-3
S = gm.GuardSettings()


def _inputs(speed=16.7, wheel_radius=0.3):
    u = {k: 0.0 for k in INPUTS}
    u.update(dt=DT, speed=speed, gps_hdop=1.0, gps_sats=10.0, mu=1.0, wheel_speed_rl=speed / wheel_radius,
             wheel_speed_rr=speed / wheel_radius)
    return u


def _run(samples, z=None, dt_nominal=DT):
    """The guard over a list of input dicts (the ECU's period ``dt_nominal``); returns the states and the clean
    inputs."""
    z = gm.initial_state() if z is None else z
    zs, cs = [], []
    for u in samples:
        z, c = gm.guard(S, z, u, dt_nominal, 0.3, NUMPY)
        zs.append(gm.STATE.as_dict(z))
        cs.append(c)
    return zs, cs


def test_the_rate_check_at_its_boundary():
    """A change of rate * dt + step from the last good value passes; a little more is replaced by the last
    good value (yaw rate: 30 rad/s^2 * 1 ms + 0.1 rad/s = 0.13 rad/s)."""
    edge = 30.0 * DT + 0.1
    for delta, passes in ((edge - 1e-9, True), (edge + 1e-9, False)):
        a, b = _inputs(), _inputs()
        b["yaw_rate"] = delta
        zs, cs = _run([a, b])
        assert cs[1]["yaw_rate"] == (delta if passes else 0.0)
        assert zs[1]["bad_samples"] == (0.0 if passes else 1.0)


@pytest.mark.parametrize("name", [c.name for c in gm.CHECKS])
def test_one_bad_sample_is_replaced_and_counted_not_a_fault(name):
    good = [_inputs() for _ in range(5)]
    for k, u in enumerate(good):
        u[name] = 0.001 * k  # moving at 1 unit/s: the last good value is the previous sample's
        if name == "speed":  # the rear wheels roll with it
            u["wheel_speed_rl"] = u["wheel_speed_rr"] = 0.001 * k / 0.3
    upper = next(c.upper for c in gm.CHECKS if c.name == name)
    for bad in (np.nan, np.inf, -np.inf, 2.0 * upper):  # beyond the range
        seq = [dict(u) for u in good]
        seq[3][name] = bad
        zs, cs = _run(seq)
        if name == "speed":  # the rear wheels' speed stands in: this sample's, 0.003 m/s
            assert cs[3][name] == pytest.approx(0.003, rel=1e-12)
        else:
            assert cs[3][name] == 0.002  # the last good value
        assert cs[4][name] == 0.004  # back at once
        assert zs[4]["bad_samples"] == 1.0 and zs[4]["fault_word"] == 0.0 and zs[4]["authority"] == 1.0


@pytest.mark.parametrize("name", [c.name for c in gm.CHECKS if c.degrading] + ["dt"])
def test_a_persistent_fault_is_named_ramped_out_and_recovered(name):
    """NaN for 0.5 s: in fault from the 50th bad sample (latch_time 0.05 s), its bit in the fault word; the
    authority falls by dt / ramp_time per period (0.2 s to 0); 0.2 s of good samples later (recover_time) the
    fault clears, the filter and the law restart on that one period and the authority ramps back at once."""
    seq = [_inputs() for _ in range(2000)]
    for u in seq[100:600]:
        u[name] = np.nan
        if name == "speed":  # with the wheel speeds in range they stand in for it (below)
            u["wheel_speed_rl"] = u["wheel_speed_rr"] = np.nan
    zs, cs = _run(seq)
    word = [z["fault_word"] for z in zs]
    bit = float(2 ** gm.FAULT_BITS[name])
    if name == "speed":  # the wheel speeds' bits too
        bit += float(2 ** gm.FAULT_BITS["wheel_speed_rl"] + 2 ** gm.FAULT_BITS["wheel_speed_rr"])
    assert word[148] == 0.0 and word[149] == bit  # the 50th bad sample
    assert all(np.isfinite(c[name]) for c in cs)
    k = np.array([z["authority"] for z in zs])
    assert k[149] == pytest.approx(1.0 - DT / S.ramp_time) and k[149 + 200] == 0.0
    # good again from sample 600: the 200th good sample (0.2 s) ends the fault
    assert word[798] == bit and word[799] == 0.0
    restarts = np.flatnonzero([z["restart"] for z in zs])
    assert list(restarts) == [0, 799]  # the first period is a start too (an ECU reset at speed), then the recovery
    assert k[798] == 0.0 and k[799] == pytest.approx(DT / S.ramp_time) and k[799 + 199] == 1.0
    assert zs[-1]["bad_samples"] == 500.0


def test_a_lost_drivers_brake_pressure_is_named_and_held_the_law_keeps_its_authority():
    """The driver's brake pressure NaN for 0.5 s from period 100, after 20 bar: it reads as 20 bar (its last good
    value: the brakes pass it on), named from the 50th bad sample (bit 8192) to the 200th good one, and the law's
    authority stays whole (nothing of the law reads it) with no restart."""
    seq = [_inputs() for _ in range(1000)]
    for k, u in enumerate(seq):
        u["brake_pressure_driver"] = 2e6 if not 100 <= k < 600 else np.nan
    zs, cs = _run(seq)
    bit = float(2 ** gm.FAULT_BITS["brake_pressure_driver"])
    assert bit == 8192.0 and all(cs[k]["brake_pressure_driver"] == 2e6 for k in range(1000))
    word = [z["fault_word"] for z in zs]
    assert word[148] == 0.0 and word[149] == bit and word[798] == bit and word[799] == 0.0
    assert all(z["authority"] == 1.0 for z in zs) and [k for k, z in enumerate(zs) if z["restart"]] == [0]


def test_a_restart_hold_keeps_the_authority_out():
    """With restart_hold 0.5 s the authority stays 0 for 500 periods after the restart, then ramps."""
    s = gm.GuardSettings(restart_hold=0.5)
    seq = [_inputs() for _ in range(2000)]
    for u in seq[100:600]:
        u["yaw_rate"] = np.nan
    z, k = gm.initial_state(), []
    for u in seq:
        z, _ = gm.guard(s, z, u, DT, 0.3, NUMPY)
        k.append(gm.STATE.as_dict(z)["authority"])
    assert k[799 + 499] == 0.0 and k[799 + 500] == pytest.approx(DT / s.ramp_time)


def test_bad_period_uses_the_nominal_one():
    """Not positive, not a number, beyond dt_max, or outside [0.5, 1.5] x the nominal period (dt_band 0.5; the
    band's edges a part in 1e9 inside and outside): the nominal period stands in. Without the band every period
    up to dt_max is used as given."""
    lo, hi = (1.0 - S.dt_band) * DT, (1.0 + S.dt_band) * DT
    for dt, used in ((-1e-3, False), (0.0, False), (np.nan, False), (1.0, False), (lo * (1 - 1e-9), False),
                     (lo * (1 + 1e-9), True), (hi * (1 - 1e-9), True), (hi * (1 + 1e-9), False), (2e-3, False)):
        seq = [_inputs(), _inputs()]
        seq[1]["dt"] = dt
        _, cs = _run(seq)
        assert cs[1]["dt"] == (dt if used else DT), dt
    wide = gm.GuardSettings(dt_band=None)
    for dt, used in ((2e-3, True), (0.1, True), (0.1 * (1 + 1e-9), False)):
        z, c = gm.guard(wide, gm.initial_state(), {**_inputs(), "dt": dt}, DT, 0.3, NUMPY)
        assert c["dt"] == (dt if used else DT), dt


def test_a_period_reported_twice_too_long_is_a_fault_of_dt():
    """A 1 kHz step told 2 ms (a clock at half rate, a counter read twice): each period is replaced by the nominal
    one, and the 50th in a row sets the dt bit (1); 0.2 s of good periods clear it."""
    seq = [_inputs() for _ in range(400)]
    for u in seq[:100]:
        u["dt"] = 2e-3
    zs, cs = _run(seq)
    assert all(c["dt"] == DT for c in cs)
    assert zs[48]["fault_word"] == 0.0 and zs[49]["fault_word"] == 1.0
    assert zs[100 + 198]["fault_word"] == 1.0 and zs[100 + 199]["fault_word"] == 0.0


def test_bad_fix_mu_and_wheel_speeds_read_as_absent():
    seq = [_inputs(), _inputs()]
    seq[1].update(gps_valid=1.0, gps_course=np.nan, mu=np.nan, wheel_speed_rl=np.inf)
    _, cs = _run(seq)
    assert cs[1]["gps_valid"] == 0.0 and cs[1]["gps_course"] == 0.0
    assert cs[1]["mu"] == gm.MU_NO_SENSOR
    assert cs[1]["wheel_speed_rl"] == pytest.approx(16.7 / 0.3)


@pytest.fixture(scope="module")
def straight():
    """The compact-ev ECU settled on a straight road at 60 km/h (3 s, 5 Hz course fixes): state and inputs."""
    p = load_vehicle("compact-ev")
    ecu = EcuDesign.from_designs(design_filter("dakf", p, control=True, kinematic=True), TwoDofDesign(p.as_nominal()))
    u = INPUTS.pack(**_inputs(60 / 3.6, ecu.wheel_radius))
    z = ecu.initial_state()
    for k in range(3000):
        u[INPUTS.index("gps_valid")] = float(k % 200 == 0)
        z, y = ecu_step(ecu, z, u, None, NUMPY)
    y = dict(zip(OUTPUTS, y))
    assert y["yaw_moment_cmd"] == 0.0 and y["steer_cmd"] == 0.0 and y["fault_word"] == 0.0
    return ecu, z, u


@pytest.mark.parametrize("name", ["speed", "steer", "yaw_rate", "ay", "steer_cmd_driver", "yaw_moment_applied",
                                  "mu", "wheel_speed_rl", "gps_course", "dt"])
def test_one_bad_sample_on_a_straight_road_does_nothing(straight, name):
    """One NaN (and one dt of -1 ms) on a straight road at 60 km/h: every output finite on every period, no
    steer and no yaw moment (the input replaced by its last good value; the course fix dropped)."""
    ecu, z, u0 = straight
    for bad in ((np.nan, -1e-3) if name == "dt" else (np.nan, np.inf)):
        zz = z.copy()
        for k in range(500):
            u = u0.copy()
            u[INPUTS.index("gps_valid")] = float(k % 200 == 0)
            if k == 0:
                u[INPUTS.index(name)] = bad
                if name == "gps_course":
                    u[INPUTS.index("gps_valid")] = 1.0
            zz, y = ecu_step(ecu, zz, u, None, NUMPY)
            assert np.all(np.isfinite(y)) and np.all(np.isfinite(zz))
            out = dict(zip(OUTPUTS, y))
            assert out["steer_cmd"] == 0.0 and out["yaw_moment_cmd"] == 0.0, (name, k, out)
        assert out["bad_samples"] == 1.0 and out["fault_word"] == 0.0


def test_a_non_finite_state_restarts(straight):
    """A NaN in the ECU's state (memory corruption, an overflow): the step restarts the filter and the law
    from their initial state on that period, flags it (bit 11) and never outputs a non-finite command."""
    ecu, z, u = straight
    zz = z.copy()
    zz[5] = np.nan
    zz, y = ecu_step(ecu, zz, u, None, NUMPY)
    out = dict(zip(OUTPUTS, y))
    assert out["fault_word"] == 2.0 ** gm.FAULT_BITS["state"] and np.all(np.isfinite(y)) and np.all(np.isfinite(zz))
    zz, y = ecu_step(ecu, zz, u, None, NUMPY)
    assert dict(zip(OUTPUTS, y))["fault_word"] == 0.0


def test_the_gps_is_in_fault_after_three_bad_fixes_and_back_after_five_good():
    """Counted in fixes (5 Hz: one every 200 samples), not in periods: the samples between fixes say nothing."""
    seq = [_inputs() for _ in range(4000)]
    fixes = list(range(0, 4000, 200))
    for k in fixes:
        seq[k].update(gps_valid=1.0, gps_course=0.0)
    for k in fixes[2:5]:  # three bad fixes in a row
        seq[k]["gps_course"] = np.nan
    zs, cs = _run(seq)
    bit = 2.0 ** gm.FAULT_BITS["gps"]
    word = [z["fault_word"] for z in zs]
    assert word[fixes[3]] == 0.0 and word[fixes[4]] == bit  # the third bad fix
    assert word[fixes[9] - 1] == bit and word[fixes[9]] == 0.0  # the fifth good fix after them
    assert all(zs[k]["authority"] == 1.0 for k in range(4000))  # the filter bridges a GPS outage: no ramp
    assert [c["gps_valid"] for c in cs if c["gps_valid"]] == [1.0] * (len(fixes) - 3)


def test_an_accelerometer_spike_inside_its_range_is_replaced():
    """A 40 m/s^2 spike (inside +-50) from 0: more than 500 m/s^3 x 1 ms + 20 m/s^2 from the last good value."""
    seq = [_inputs() for _ in range(3)]
    seq[1]["ay"] = 40.0
    zs, cs = _run(seq)
    assert cs[1]["ay"] == 0.0 and zs[1]["bad_samples"] == 1.0


def test_a_calibration_outside_its_limits_takes_the_authority():
    """A calibration value outside the limits the A2L declares (k_beta 100.5 against [0.01, 100]; or NaN) is a
    fault from the 50th period, bit 12, and the law ramps out; back inside, it recovers."""
    p = load_vehicle("compact-ev")
    ecu = EcuDesign.from_designs(design_filter("dakf", p, control=True, kinematic=True), TwoDofDesign(p.as_nominal()))
    names = [c.name for c in ecu.calibration()]
    good = [c.value for c in ecu.calibration()]
    u = INPUTS.pack(**_inputs(20.0, ecu.wheel_radius))
    for wrong in (100.5, np.nan):
        cal = list(good)
        cal[names.index("k_beta")] = wrong
        z = ecu.initial_state()
        from evstab.toolkit.ecu.step import ecu_guard
        words, ks = [], []
        for k in range(500):
            zg, _ = ecu_guard(ecu, z, u, NUMPY, cal if k < 300 else good)
            z = np.concatenate([z[:ecu.layout.index("guard")], zg])
            st = gm.STATE.as_dict(zg)
            words.append(st["fault_word"])
            ks.append(st["authority"])
        assert words[48] == 0.0 and words[49] == 2.0 ** gm.FAULT_BITS["calibration"]
        assert ks[49 + 200] == 0.0 and words[300 + 199] == 0.0  # back after 0.2 s of a good calibration
    # at the limit itself it is good
    cal = list(good)
    cal[names.index("k_beta")] = 100.0
    zg, _ = ecu_guard(ecu, ecu.initial_state(), u, NUMPY, cal)
    assert gm.STATE.as_dict(zg)["bad_samples"] == 0.0


V = 16.7
BAND = S.consistency_ay + S.consistency_rate * V
"""[m/s^2] Where ``|a_y - v r|`` starts to disagree at 16.7 m/s: 0.3 + 0.02 x 16.7 = 0.634."""


def _held(r, ay, n, speed=V):
    """``n`` periods of the yaw rate held at ``r`` from the first (which has no last value to check against) with
    the lateral acceleration ``ay``."""
    seq = [_inputs(speed) for _ in range(n)]
    for u in seq:
        u["yaw_rate"], u["ay"] = r, ay
    return _run(seq)


@pytest.mark.parametrize("excess, stuck", [(1.0 - 1e-6, False), (1.0 + 1e-6, True)])
def test_a_held_yaw_rate_that_disagrees_is_stuck(excess, stuck):
    """A yaw rate held to the bit while ``|a_y - v r|`` is just beyond the band (0.634 m/s^2 at 16.7 m/s) fails
    from the period it has been held 20 ms (stuck_time; period k repeats the first period's value k times: k ms)
    and reads as ``a_y / v``; 50 ms of that latch the fault (bit 8). Just inside the band it passes: a quantised
    CAN signal in a steady turn holds its value as long as the turn lasts."""
    r = excess * BAND / V  # a_y = 0: the disagreement is v r
    zs, cs = _held(r, 0.0, 200)
    assert cs[19]["yaw_rate"] == r  # held 19 ms
    assert cs[20]["yaw_rate"] == (0.0 if stuck else r)  # held 20 ms: a_y / v = 0 when stuck
    assert zs[-1]["bad_samples"] == (180.0 if stuck else 0.0)
    word = [z["fault_word"] for z in zs]
    assert word[68] == 0.0 and word[69] == (8.0 if stuck else 0.0)  # the 50th stuck period


def test_a_quantised_yaw_rate_in_a_steady_turn_is_not_stuck():
    """A CAN yaw rate quantised in 1.28 deg/s steps, held for 2 s in a steady 4 m/s^2 turn at 16.7 m/s: the
    lateral acceleration is v r to within one step (0.022 rad/s x 16.7 = 0.37 m/s^2, inside the 0.634 band)."""
    step = np.radians(1.28)
    r = step * np.round(4.0 / V / step)
    zs, cs = _held(r, 4.0, 2000)
    assert abs(4.0 - V * r) > 0.1  # the quantisation is felt
    assert all(c["yaw_rate"] == r for c in cs) and zs[-1]["bad_samples"] == 0.0


def test_a_live_yaw_rate_that_disagrees_is_taken():
    """In a slide the yaw rate and the lateral acceleration disagree (``a_y - v r = v beta'``): a gyro whose
    readings move (1 mrad/s of noise) is taken however far they disagree; so is a held one below 5 m/s."""
    rng = np.random.default_rng(0)
    seq = [_inputs() for _ in range(300)]
    for u in seq:
        u["yaw_rate"], u["ay"] = 0.3 + 1e-3 * rng.standard_normal(), 1.0  # beta' = -0.24 rad/s
    zs, cs = _run(seq)
    assert zs[-1]["bad_samples"] == 0.0 and all(c["yaw_rate"] == u["yaw_rate"] for c, u in zip(cs, seq))
    zs, cs = _held(0.3, 0.0, 300, speed=4.9)
    assert zs[-1]["bad_samples"] == 0.0


def test_a_stuck_yaw_rate_recovers_when_it_moves_again():
    """Stuck for 0.5 s in a turn whose lateral acceleration rises, then live: the fault clears 0.2 s after the
    first live reading (recover_time) and the filter and the law restart on that period."""
    seq = [_inputs() for _ in range(1200)]
    rng = np.random.default_rng(1)
    for k, u in enumerate(seq):
        u["ay"] = min(0.01 * k, 4.0)
        u["yaw_rate"] = u["ay"] / V + (1e-3 * rng.standard_normal() if not 100 <= k < 600 else 0.0)
    for u in seq[100:600]:
        u["yaw_rate"] = seq[99]["yaw_rate"]
    zs, cs = _run(seq)
    word = np.array([z["fault_word"] for z in zs])
    assert word[599] == 8.0 and word[600 + 198] == 8.0 and word[600 + 199] == 0.0
    assert zs[600 + 199]["restart"] == 1.0
    stuck = [k for k in range(100, 600) if cs[k]["yaw_rate"] != seq[k]["yaw_rate"]]
    assert stuck and all(cs[k]["yaw_rate"] == pytest.approx(seq[k]["ay"] / V) for k in stuck)


@pytest.mark.parametrize("delta, passes", [(-1e-9, True), (1e-9, False)])
def test_a_can_yaw_rate_moves_on_by_its_message_interval(delta, passes):
    """A yaw rate that held its value 9 ms (a 100 Hz CAN message) may move by 30 rad/s^2 x (1 + 9) ms + 0.1 rad/s
    on the next period; a little more is a bad sample."""
    seq = [_inputs() for _ in range(12)]
    for u in seq[1:11]:
        u["yaw_rate"], u["ay"] = 0.01, 0.01 * V
    edge = 0.01 + 30.0 * 10 * DT + 0.1 + delta
    seq[11]["yaw_rate"], seq[11]["ay"] = edge, edge * V
    zs, cs = _run(seq)
    assert cs[11]["yaw_rate"] == (edge if passes else 0.01)


def test_the_rear_wheels_stand_in_for_a_speed_in_fault():
    """Speed NaN for 0.5 s with both rear wheel speeds in range (18 and 22 rad/s on a 0.3 m wheel): it reads
    as their mean times the radius, 6.0 m/s, from its first bad sample; it is named in the fault word from the
    50th (bit 2) but the law keeps its authority (exactly 1) and nothing restarts at the recovery. With one
    wheel speed out of range too, the authority ramps out as for any input the law depends on."""
    seq = [_inputs() for _ in range(1000)]
    for u in seq[100:600]:
        u["speed"], u["wheel_speed_rl"], u["wheel_speed_rr"] = np.nan, 18.0, 22.0
    zs, cs = _run(seq)
    assert all(cs[k]["speed"] == pytest.approx(6.0, rel=1e-15) for k in range(100, 600))
    assert zs[148]["fault_word"] == 0.0 and zs[149]["fault_word"] == 2.0
    assert all(z["authority"] == 1.0 for z in zs) and [k for k, z in enumerate(zs) if z["restart"]] == [0]
    for u in seq[100:600]:
        u["wheel_speed_rr"] = 1e6  # beyond WHEEL_SPEED_MAX
    zs, cs = _run(seq)
    assert cs[100]["speed"] == seq[99]["speed"]  # the last good value
    assert zs[149 + 200]["authority"] == 0.0


def _fixes(n, yaw_rate, course, every=200, dt=DT):
    """``n`` periods of ``dt`` at 16.7 m/s with the gyro reading ``yaw_rate(k)`` and a fix every ``every`` periods
    (5 Hz at 1 ms) whose course is ``course(k)``."""
    seq = [_inputs() for _ in range(n)]
    for k, u in enumerate(seq):
        u["dt"] = dt
        u["yaw_rate"], u["ay"] = yaw_rate(k), V * yaw_rate(k)  # a car that does not slide: the gyro agrees
        if k % every == 0:
            u.update(gps_valid=1.0, gps_course=course(k))
    return seq


@pytest.mark.parametrize("share, stuck", [(1.0 - 1e-6, False), (1.0 + 1e-6, True)])
def test_a_repeated_course_after_a_turn_is_stuck(share, stuck):
    """A second fix with the first one's course to the bit, 200 periods later, after a steady yaw rate ``r``: the
    heading change the guard holds at it is the leaky sum over periods 1-199 (period 0 is the fix, which resets
    it), ``r dt sum_{j<199} L^j = r tau (1 - L^199)``, ``L = 1 - dt / tau``. At ``share`` of course_stuck_turn
    (0.035 rad: 2 deg) the fix is used; just beyond, dropped and counted."""
    leak = 1.0 - DT / S.course_stuck_tau
    r = share * S.course_stuck_turn / (S.course_stuck_tau * (1.0 - leak ** 199))
    zs, cs = _run(_fixes(201, lambda k: r, lambda k: 0.3))
    assert cs[0]["gps_valid"] == 1.0
    assert cs[200]["gps_valid"] == (0.0 if stuck else 1.0)
    assert zs[200]["bad_samples"] == (1.0 if stuck else 0.0)


def test_a_stuck_course_in_a_turn_is_named_and_recovers():
    """The course stops at its value of period 600 while a 0.3 rad/s turn goes on to period 2600: at the next fix
    the gyro has turned by 0.3 tau (1 - L^199) = 0.054 rad since (above 0.035), so from it each repeated fix is
    dropped, the third dropped one (period 1200) sets the GPS bit (32), and once the course moves again the
    fifth good fix (period 3400) clears it; the law keeps its authority (the filter bridges a GPS outage)."""
    r, held = 0.3, 0.3 * DT * 600
    seq = _fixes(5000, lambda k: r if k < 2600 else 0.0, lambda k: r * DT * min(k, 600))
    for k in range(2600, 5000, 200):
        seq[k]["gps_course"] = r * DT * 2600 + 1e-3 * (k - 2600) / 200  # moving on, where the heading is
    zs, cs = _run(seq)
    used = {k: cs[k]["gps_valid"] for k in range(0, 5000, 200)}
    assert seq[800]["gps_course"] == held and [used[k] for k in range(0, 800, 200)] == [1.0] * 4
    assert [used[k] for k in range(800, 2600, 200)] == [0.0] * 9
    assert all(used[k] == 1.0 for k in range(2600, 5000, 200))
    bit = 2.0 ** gm.FAULT_BITS["gps"]
    assert zs[1199]["fault_word"] == 0.0 and zs[1200]["fault_word"] == bit
    assert zs[3399]["fault_word"] == bit and zs[3400]["fault_word"] == 0.0
    assert zs[-1]["bad_samples"] == 9.0 and all(z["authority"] == 1.0 for z in zs)


def test_a_quantised_course_in_a_steady_turn_is_not_stuck():
    """A receiver that reports its course in 1 deg steps, at 5 Hz, through a 20 s turn of 0.05 rad/s (2.9 deg/s:
    a step every 1.7 fixes, so some fixes repeat the last one): the heading has moved by less than one step,
    0.0175 rad, when the course changes, inside the 0.035 rad bound. Every fix is used."""
    q, dt = np.radians(1.0), 0.01  # a 100 Hz ECU
    zs, cs = _run(_fixes(2000, lambda k: 0.05, lambda k: q * np.round(0.05 * dt * k / q), every=20, dt=dt),
                  dt_nominal=dt)
    fixes = [cs[k]["gps_valid"] for k in range(0, 2000, 20)]
    courses = [q * np.round(0.05 * dt * k / q) for k in range(0, 2000, 20)]
    assert sum(a == b for a, b in zip(courses[1:], courses[:-1])) > 30  # repeats the guard must let through
    assert fixes == [1.0] * 100 and zs[-1]["bad_samples"] == 0.0


def test_a_gyro_bias_on_a_long_straight_does_not_make_a_steady_course_stuck():
    """On a straight road a course quantised to 1 deg repeats for minutes; a 3 mrad/s gyro bias would add up to
    the bound in 12 s, the leak holds it at ``b tau`` = 0.003 rad. Every fix of 120 s (100 Hz) is used."""
    zs, cs = _run(_fixes(12000, lambda k: 0.003, lambda k: np.radians(30.0), every=20, dt=0.01), dt_nominal=0.01)
    assert all(cs[k]["gps_valid"] == 1.0 for k in range(0, 12000, 20))
    # the leaky sum's limit b dt / (1 - L) = b tau, reached to 0.99^11999 (0): to rounding
    assert zs[-1]["course_turn"] == pytest.approx(0.003, rel=1e-9)


TRACK = 1.5
"""[m] The rear track of the vote's tests (the wheels' yaw rate is ``(w_rr - w_rl) R / t_r``, R = 0.3 m)."""


VOTE = gm.GuardSettings(vote_rate=0.05)
"""The guard with the vote on the yaw rate (its default)."""
SETTLE = 1000
"""Periods of steady inputs before a test's event: past ``vote_settle`` (200), and the low-passed wheels and
``a_y / v`` within (20/21)^1000 = 6e-22 of their inputs (a boundary case's 1e-6 of 0.03 rad/s is 3e-8)."""


def _voted(samples, law_blend=0.0, settings=VOTE):
    """:func:`_run` with the vote on and the rear track given (the yaw rate is voted against the wheels and
    ``a_y``), and the law's authority ``law_blend``. The ECU is taken to have commanded the yaw moment applied
    (the guard compares the applied one with the command)."""
    z, zs, cs = gm.initial_state(), [], []
    for u in samples:
        z, c = gm.guard(settings, z, u, DT, 0.3, NUMPY, track_rear=TRACK, law_blend=law_blend)
        z = gm.with_command(z, u["yaw_moment_applied"])
        zs.append(gm.STATE.as_dict(z))
        cs.append(c)
    return zs, cs


def _turning(n, gyro, ay, r_wheels, nz=0.0, speed=V, k0=0):
    """``n`` periods with the gyro at ``gyro`` (moving by 1e-9 rad/s every other period: live, not held; well
    inside the boundary cases' 1e-6), the lateral acceleration ``ay``, the rear wheels apart by the yaw rate
    ``r_wheels`` and the yaw moment ``nz`` applied."""
    seq = [_inputs(speed) for _ in range(n)]
    dw = r_wheels * TRACK / 0.3 / 2.0
    for k, u in enumerate(seq):
        u.update(yaw_rate=gyro + 1e-9 * ((k0 + k) % 2), ay=ay, yaw_moment_applied=nz,
                 wheel_speed_rl=speed / 0.3 - dw, wheel_speed_rr=speed / 0.3 + dw)
    return seq


def _settled(gyro, ay, r_wheels, nz=0.0):
    """:data:`SETTLE` periods of :func:`_turning` (the gyro agreeing with what the test's event starts from)."""
    return _turning(SETTLE, gyro, ay, r_wheels, nz)


@pytest.mark.parametrize("share, out", [(1.0 - 1e-6, False), (1.0 + 1e-6, True)])
def test_the_wheels_and_the_accelerometer_outvote_an_offset_gyro(share, out):
    """Straight road (wheels together, a_y 0) at 16.7 m/s; then the gyro at ``share`` of vote_rate (0.05 rad/s;
    v r = 0.84 m/s^2, beyond the 0.634 band): just beyond, it is outvoted from its first period and reads as
    a_y / v = 0, and 50 ms latch the fault (bit 8); just inside, it is taken."""
    r = share * VOTE.vote_rate
    zs, cs = _voted(_settled(0.0, 0.0, 0.0) + _turning(100, r, 0.0, 0.0, k0=SETTLE))
    assert all(c["yaw_rate"] == 1e-9 * (k % 2) for k, c in enumerate(cs[:SETTLE]))
    assert all(c["yaw_rate"] == (0.0 if out else r + 1e-9 * (k % 2)) for k, c in enumerate(cs[SETTLE:]))
    assert zs[SETTLE + 48]["fault_word"] == 0.0 and zs[SETTLE + 49]["fault_word"] == (8.0 if out else 0.0)


@pytest.mark.parametrize("share, out", [(1.0 - 1e-6, True), (1.0 + 1e-6, False)])
def test_the_accelerometer_must_side_with_the_wheels(share, out):
    """a_y 0, the wheels (and the gyro) at r_w, then a 0.1 rad/s gyro: a_y / v must be nearer the wheels than half
    the gyro's distance from them, v r_w < 0.5 v (0.1 - r_w), i.e. r_w < 0.1 / 3. At ``share`` of that edge (the
    gyro 0.067 rad/s from the wheels, beyond vote_rate): inside, outvoted; beyond, the three disagree and the
    gyro is taken."""
    r_w = share * 0.1 / 3.0
    _, cs = _voted(_settled(r_w, 0.0, r_w) + _turning(3, 0.1, 0.0, r_w))
    assert cs[-1]["yaw_rate"] == (0.0 if out else 0.1)


def test_the_vote_starts_only_while_the_law_is_passive_and_the_motors_quiet():
    """The same offset gyro while the law has any authority (blend 1e-9), or with 200 N m + 1e-9 of yaw moment
    applied (the motors' torque difference slips the rear wheels apart): taken. At 200 N m exactly: outvoted."""
    for blend, nz, out in ((1e-9, 0.0, False), (0.0, VOTE.vote_yaw_moment * (1 + 1e-9), False),
                           (0.0, VOTE.vote_yaw_moment, True)):
        zs, _ = _voted(_settled(0.0, 0.0, 0.0, nz) + _turning(10, 0.1, 0.0, 0.0, nz=nz), law_blend=blend)
        assert zs[-1]["bad_samples"] == (10.0 if out else 0.0), (blend, nz)


def test_the_vote_waits_vote_settle_after_a_yaw_moment():
    """A yaw moment of 201 N m for 50 periods, then none; the gyro at 0.1 rad/s from the 150th quiet period: the
    motors have been quiet for vote_settle (0.2 s) at the 200th, the first outvoted sample (the low-passed wheels
    remember the slip the moment made)."""
    seq = _turning(50, 0.0, 0.0, 0.0, nz=VOTE.vote_yaw_moment + 1.0) + _turning(150, 0.0, 0.0, 0.0, k0=50) + \
        _turning(100, 0.1, 0.0, 0.0, k0=200)
    _, cs = _voted(seq)
    taken = [c["yaw_rate"] != 0.0 for c in cs[200:]]
    assert taken[:50] == [True] * 50 and not any(taken[50:])


def test_an_outvoted_gyro_stays_out_while_it_is_half_as_far_from_the_wheels():
    """Outvoted at 0.1 rad/s on a straight road, then a wheel sample reading 1 rad/s of yaw rate (the low-passed
    wheels at 1/21: a_y / v no longer sides with them, the start fails) keeps it out; the wheels back together,
    their low-passed yaw rate f decays by 20/21 a period, and a gyro at f + 0.045 rad/s (below vote_rate, but more
    than half of it from the wheels and still beyond the accelerometer's band, 0.038 rad/s at this speed) stays
    out; at f + 0.024 it is taken."""
    lag = DT / (VOTE.vote_tau + DT)
    f1 = 1.0 * lag
    f2, f3 = f1 * (1 - lag), f1 * (1 - lag) ** 2
    seq = _settled(0.0, 0.0, 0.0) + _turning(2, 0.1, 0.0, 0.0) + _turning(1, 0.1, 0.0, 1.0)
    _, cs = _voted(seq)
    assert abs(f1) > 0.5 * abs(0.1 - f1) and cs[-1]["yaw_rate"] == 0.0  # kept, not started
    seq += _turning(1, f2 + 0.045, 0.0, 0.0) + _turning(1, f3 + 0.024, 0.0, 0.0)
    _, cs = _voted(seq)
    assert [c["yaw_rate"] for c in cs[SETTLE:]] == [0.0, 0.0, 0.0, 0.0, f3 + 0.024]


def test_a_sample_of_wheel_noise_does_not_outvote_a_live_gyro():
    """The gyro and the rear wheels at 0.045 rad/s, a_y 0 (a sideslip rate of -0.045 rad/s: the gyro beyond the
    accelerometer's band); one wheel sample reads -0.01 rad/s (0.055 from the gyro, a_y / v nearer it): low-passed
    it moves the wheels by 0.055/21 and the gyro is taken."""
    seq = _settled(0.045, 0.0, 0.045) + _turning(1, 0.045, 0.0, -0.01) + _turning(10, 0.045, 0.0, 0.045)
    zs, _ = _voted(seq)
    assert zs[-1]["bad_samples"] == 0.0


def test_a_slide_is_not_outvoted():
    """A slide at 16.7 m/s: the gyro and the rear wheels at 0.3 rad/s (the rear axle turns with the body), a_y 1
    m/s^2 (beta' = -0.24 rad/s): the accelerometer disagrees with the gyro, the wheels do not: taken, every
    sample."""
    zs, cs = _voted(_turning(300, 0.3, 1.0, 0.3))
    assert zs[-1]["bad_samples"] == 0.0


def test_the_vote_is_on_by_default():
    """The default guard outvotes the offset gyro on a straight road; with ``vote_rate`` None it is taken."""
    assert S.vote_rate == VOTE.vote_rate
    seq = _settled(0.0, 0.0, 0.0) + _turning(10, 0.1, 0.0, 0.0)
    assert _voted(seq, settings=S)[0][-1]["bad_samples"] == 10.0
    off = gm.GuardSettings(vote_rate=None)
    assert _voted(seq, settings=off)[0][-1]["bad_samples"] == 0.0


def test_without_wheel_sensors_the_vote_holds_on_a_straight_road_only():
    """Without wheel-speed sensors the ECU is given speed / R for both: the wheels' yaw rate is 0. A 0.1 rad/s
    offset on a straight road is outvoted; a steady 4 m/s^2 turn (the gyro and a_y / v agree) is taken."""
    zs, _ = _voted(_settled(0.0, 0.0, 0.0) + _turning(100, 0.1, 0.0, 0.0))
    assert zs[-1]["bad_samples"] == 100.0
    zs, _ = _voted(_turning(2000, 4.0 / V, 4.0, 0.0))
    assert zs[-1]["bad_samples"] == 0.0


@pytest.mark.parametrize("share, out", [(1.0 - 1e-6, True), (1.0 + 1e-6, False)])
def test_the_vote_starts_only_in_nearly_straight_driving(share, out):
    """The wheels together, a_y at ``share`` of vote_ay (1 m/s^2), then the gyro at 0.075 and 0.15 rad/s (two steps
    within the rate test's 0.13 rad/s; at 0.075, a_y / v, 0.06 rad/s, is not nearer the wheels than half the gap):
    below vote_ay the two outvote the gyro at 0.15, from it the vote does not start (at the limit a slipping
    wheel can side with a_y / v)."""
    ay = share * VOTE.vote_ay
    _, cs = _voted(_settled(0.0, ay, 0.0) + _turning(1, 0.075, ay, 0.0) + _turning(2, 0.15, ay, 0.0))
    assert cs[-3]["yaw_rate"] == 0.075
    assert cs[-2]["yaw_rate"] == (pytest.approx(ay / V) if out else 0.15)


def _steering(n, steer, driver, law_blend=0.0):
    """``n`` periods at 16.7 m/s with the road-wheel angle ``steer(k)`` and the driver's ``driver(k)``, the law's
    authority ``law_blend`` throughout."""
    seq = [_inputs() for _ in range(n)]
    for k, u in enumerate(seq):
        u["steer"], u["steer_cmd_driver"] = steer(k), driver(k)
    z, zs, cs = gm.initial_state(), [], []
    for u in seq:
        z, c = gm.guard(S, z, u, DT, 0.3, NUMPY, law_blend=law_blend)
        zs.append(gm.STATE.as_dict(z))
        cs.append(c)
    return zs, cs


@pytest.mark.parametrize("share, apart", [(1.0 - 1e-6, False), (1.0 + 1e-6, True)])
def test_the_drivers_angle_and_the_road_wheels_agree_while_the_law_is_passive(share, apart):
    """Road wheels at 0.01 rad, the law passive from the start: from period 300 the driver's reading is ``share`` of
    the band away (0.5 deg + 10 % of 0.01 rad = 0.0097 rad; inside the rate test's 0.015 rad step). Just beyond it
    both are replaced by their last good values; just inside, taken."""
    band = S.steer_agree + S.steer_agree_share * 0.01
    zs, cs = _steering(310, lambda k: 0.01, lambda k: 0.01 + (share * band if k >= 300 else 0.0))
    assert cs[305]["steer_cmd_driver"] == (0.01 if apart else 0.01 + share * band)
    assert cs[305]["steer"] == 0.01 and zs[305]["bad_samples"] == (6.0 if apart else 0.0)


def test_a_drivers_steer_offset_is_held_named_and_recovers():
    """A 2 deg offset on the driver's reading from period 300 to 800 (the law passive since the start): the law
    never reads it (the last good angle stands in), the 50th period apart names both angles (bits 4 and 64) and
    takes the authority, and 0.2 s after the offset ends both recover."""
    zs, cs = _steering(1100, lambda k: 0.01, lambda k: 0.01 + (np.radians(2.0) if 300 <= k < 800 else 0.0))
    assert all(c["steer_cmd_driver"] == 0.01 for c in cs)
    word = [z["fault_word"] for z in zs]
    assert word[348] == 0.0 and word[349] == 4.0 + 64.0
    assert word[800 + 198] == 68.0 and word[800 + 199] == 0.0
    assert zs[600]["authority"] == 0.0


def test_the_angles_are_not_compared_while_the_law_acts_or_has_just_stopped():
    """0.7 deg apart (beyond the band, inside the rate test's step) while the law has authority (its correction is
    on the road wheels): taken throughout; with the law passive from the start, taken until it has been passive
    for steer_settle (0.2 s: period 200, the gear following a correction out), failed from then (replaced by the
    last good value, here the same reading: counted)."""
    apart = np.radians(0.7)
    zs, cs = _steering(400, lambda k: 0.01, lambda k: 0.01 + apart * (k >= 100), law_blend=1e-9)
    assert cs[399]["steer_cmd_driver"] == 0.01 + apart and zs[399]["bad_samples"] == 0.0
    zs, _ = _steering(201, lambda k: 0.01, lambda k: 0.01 + apart * (k >= 100))
    assert zs[199]["bad_samples"] == 0.0 and zs[200]["bad_samples"] == 1.0



def _commanded(seq, cmd=0.0):
    """The guard over ``seq`` with the ECU commanding ``cmd`` N m of yaw moment every period."""
    z, zs, cs = gm.initial_state(), [], []
    for u in seq:
        z, c = gm.guard(S, z, u, DT, 0.3, NUMPY)
        z = gm.with_command(z, cmd)
        zs.append(gm.STATE.as_dict(z))
        cs.append(c)
    return zs, cs


@pytest.mark.parametrize("applied, unasked", [(S.vote_yaw_moment, False), (S.vote_yaw_moment * (1 + 1e-9), True)])
def test_a_yaw_moment_the_ecu_did_not_command_is_named(applied, unasked):
    """The ECU commands nothing; from period 300 the motors report ``applied`` N m. Above ``vote_yaw_moment`` (200)
    it is not taken (the last good value, 0, stands in) and, 50 ms on (period 349), named (bit 7) and the law's
    authority ramps out; at 200 exactly it is taken."""
    seq = [_inputs() for _ in range(600)]
    for u in seq[300:]:
        u["yaw_moment_applied"] = applied
    zs, cs = _commanded(seq)
    assert cs[300]["yaw_moment_applied"] == (0.0 if unasked else applied)
    bit = 2.0 ** gm.FAULT_BITS["yaw_moment_applied"]
    assert zs[348]["fault_word"] == 0.0 and zs[349]["fault_word"] == (bit if unasked else 0.0)
    assert (zs[-1]["authority"] == 0.0) == unasked


def test_the_applied_yaw_moment_is_compared_only_after_a_quiet_command():
    """The check starts once the ECU has commanded at most ``moment_quiet`` (50 N m) for ``vote_settle`` (0.2 s):
    the quiet time read on period ``k`` is the ``k`` periods before it, so 1,000 N m applied from the first period
    passes on periods 0-199 and fails (counted) from period 200; with 50 N m commanded, the same; with 50 N m +
    1e-9, the command is not quiet and every period passes (the motors follow a command through their lag)."""
    seq = [_inputs() for _ in range(400)]
    for u in seq:
        u["yaw_moment_applied"] = 1000.0
    for cmd, from_k in ((0.0, 200), (S.moment_quiet, 200), (S.moment_quiet * (1 + 1e-9), None)):
        zs, cs = _commanded(seq, cmd)
        counted = [z["bad_samples"] for z in zs]
        assert counted == [0.0 if from_k is None else float(max(k - from_k + 1, 0)) for k in range(400)], cmd


def _jump_limit(speed=16.7):
    """The course jump the guard lets through at ``speed`` with HDOP 1 [rad]."""
    return S.course_jump + S.course_jump_velocity / speed


@pytest.mark.parametrize("share, dropped", [(1.0 - 1e-6, False), (1.0 + 1e-6, True)])
def test_a_course_jump_beyond_what_the_lateral_acceleration_turned_is_dropped(share, dropped):
    """A turn at 0.3 rad/s in which the car does not slide (``a_y = v r``): the course moves with the integral of
    ``a_y / v`` from the last good fix, 200 periods of 0.3 rad/s * 1 ms between two fixes (the guard integrates the
    periods after the fix, through the next one). The fix of period 1000 moves ``share`` of the bound beyond that
    (0.087 rad + 0.3 m/s / 16.7 m/s): below it, used; beyond it, dropped and counted; the next fix, on the
    course again, is used."""
    r = 0.3
    seq = _fixes(1201, lambda k: r, lambda k: r * DT * k)
    seq[1000]["gps_course"] += share * _jump_limit()
    zs, cs = _run(seq)
    assert [cs[k]["gps_valid"] for k in range(0, 1000, 200)] == [1.0] * 5
    assert cs[1000]["gps_valid"] == (0.0 if dropped else 1.0) and cs[1200]["gps_valid"] == 1.0
    assert zs[1000]["bad_samples"] == (1.0 if dropped else 0.0)


def test_a_course_offset_is_named_and_taken_back_when_it_stays():
    """From period 1000 the course reads 10 deg off, and stays so, on a straight road. The fixes of periods 1000,
    1200 and 1400 are dropped, the third sets the GPS bit (32); from then each fix is compared with the one before
    it: 1600 (against 1400's, the first compared so) is taken back, and the fifth good fix after it (2400) clears
    the bit. The law keeps its authority (the filter bridges a GPS outage)."""
    seq = _fixes(3001, lambda k: 0.0, lambda k: np.radians(10.0) if k >= 1000 else 0.0)
    zs, cs = _run(seq)
    used = [cs[k]["gps_valid"] for k in range(0, 3001, 200)]
    assert used == [1.0] * 5 + [0.0] * 3 + [1.0] * 8
    bit = 2.0 ** gm.FAULT_BITS["gps"]
    assert zs[1399]["fault_word"] == 0.0 and zs[1400]["fault_word"] == bit
    assert zs[2399]["fault_word"] == bit and zs[2400]["fault_word"] == 0.0
    assert all(z["authority"] == 1.0 for z in zs)


@pytest.mark.parametrize("case", ["outage", "slow"])
def test_a_course_jump_after_an_outage_or_at_walking_pace_is_taken(case):
    """No comparison after ``course_jump_window`` (1 s) without a good fix (the integral of ``a_y / v`` drifts with
    the accelerometer's error), nor below ``consistency_speed`` (5 m/s, where the course's own noise grows): a fix
    10 deg off, 1.2 s after the last one or at 4.9 m/s, is used."""
    seq = _fixes(2201, lambda k: 0.0, lambda k: np.radians(10.0) if k >= 2200 else 0.0)
    if case == "outage":
        for u in seq[1001:2200]:
            u["gps_valid"] = 0.0
    else:
        for u in seq:
            u["speed"], u["wheel_speed_rl"], u["wheel_speed_rr"] = 4.9, 4.9 / 0.3, 4.9 / 0.3
    zs, cs = _run(seq)
    assert cs[2200]["gps_valid"] == 1.0 and zs[-1]["bad_samples"] == 0.0
