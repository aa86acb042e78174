"""The envelope's rules on hand-worked cases at each boundary (so that a wrong threshold fails a
test), its manoeuvres' geometry and physics, and the human driver."""

import dataclasses

import numpy as np
import pytest

from evstab.plants import G, load_vehicle
from evstab.plants.maneuvers import iso3888_2, iso3888_2_lanes, slalom, step_steer
from evstab.plants.paths import HumanDriver, Path
from evstab.toolkit.verdicts import envelope as ev


def m(beta=1.0, ay=5.0, cones=0, steer=0.0, nz=0.0, dev=float("nan")):
    return ev.Metrics(peak_beta_deg=beta, peak_ay=ay, cones_hit=cones, added_steer_deg=steer, peak_yaw_moment=nz,
                      deviation_m=dev)


FAR = 0.9 * G  # [m/s^2] a limit manoeuvre on mu 1: the quiet rule does not apply


@pytest.mark.parametrize("ctl, ok", [(5.49, True), (5.51, False)])
def test_no_harm_allows_ten_percent_more_sideslip(ctl, ok):
    # car alone 5 deg: the bound is max(1.1 x 5, 5 + 0.3) = 5.5 deg
    assert (not ev.judge(m(ctl, FAR), m(5.0, FAR), 1.0)) == ok


@pytest.mark.parametrize("ctl, ok", [(1.29, True), (1.31, False)])
def test_no_harm_allows_0_3_deg_more_sideslip_where_that_is_more(ctl, ok):
    # car alone 1 deg: max(1.1, 1.3) = 1.3 deg
    assert (not ev.judge(m(ctl, FAR), m(1.0, FAR), 1.0)) == ok


def test_no_harm_counts_cones_and_slides():
    broken = ev.judge(m(1.0, FAR, cones=1), m(1.0, FAR), 1.0)
    assert len(broken) == 1 and "1 cones hit" in broken[0]
    assert ev.judge(m(1.0, FAR, cones=2), m(1.0, FAR, cones=1), 1.0) == []  # the car alone failed too


@pytest.mark.parametrize("alone, broken", [(9.9, False), (10.1, True)])
def test_a_slide_is_past_10_deg(alone, broken):
    # controlled 6 deg: within the no-harm bound of a car alone at 9.9 deg (not a slide), but not
    # below 5 deg where the car alone slides (10.1 deg)
    assert bool(ev.judge(m(6.0, FAR), m(alone, FAR), 1.0)) == broken


@pytest.mark.parametrize("ctl, ok", [(4.9, True), (5.1, False)])
def test_where_the_car_alone_slides_the_controlled_car_stays_below_5_deg(ctl, ok):
    assert (not ev.judge(m(ctl, FAR), m(30.0, FAR), 1.0)) == ok
    assert (not ev.judge(m(ctl, FAR), ev.LOST, 1.0)) == ok  # the car alone rolled over or diverged


@pytest.mark.parametrize("alone_g, mu, quiet", [(0.59, 1.0, True), (0.61, 1.0, False), (0.29, 0.5, True),
                                                (0.31, 0.5, False)])
def test_normal_driving_is_below_0_6_of_the_friction_limit(alone_g, mu, quiet):
    # 0.5 deg of added steer is too much in normal driving and allowed at the limit
    broken = ev.judge(m(1.0, alone_g * G, steer=0.5), m(1.0, alone_g * G), mu)
    assert bool(broken) == quiet and all("quiet" in b for b in broken)


@pytest.mark.parametrize("steer, nz, ok", [(0.24, 0.0, True), (0.26, 0.0, False), (0.0, 299.0, True),
                                           (0.0, 301.0, False)])
def test_quiet_means_a_quarter_degree_and_300_n_m(steer, nz, ok):
    assert (not ev.judge(m(1.0, 3.0, steer=steer, nz=nz), m(1.0, 3.0), 1.0)) == ok


def test_a_disturbance_is_not_normal_driving():
    # split friction (mu 0.2 on the right; 1 m/s^2 is below 0.6 mu g): the law rejecting the road's yaw moment breaks no quiet rule, but it
    # must still do no harm (1.0 deg alone: 1.3 deg allowed)
    assert ev.judge(m(1.0, 1.0, steer=0.6, nz=700.0), m(1.0, 1.0), 0.2, disturbance=True) == []
    assert len(ev.judge(m(1.0, 1.0, steer=0.6, nz=700.0), m(1.0, 1.0), 0.2)) == 2
    assert ev.judge(m(1.31, 1.0, steer=0.6), m(1.0, 1.0), 0.2, disturbance=True)[0].startswith("no harm")
    kinds = {c.kind for c in ev.cases() if c.disturbance}
    assert kinds == {"crosswind", "split-mu-accel", "split-mu-lane-change"}


@pytest.mark.parametrize("ctl, ok", [(0.49, True), (0.51, False)])
def test_crosswind_deviation_at_most_half(ctl, ok):
    # the gust is rejected with steer and yaw moment beyond the quiet rule's: no quiet rule here
    assert (not ev.judge(m(0.2, 1.0, dev=ctl, steer=0.9, nz=800.0), m(0.2, 1.0, dev=1.0), 1.0)) == ok


class _Run:
    """A stand-in for a SimResult: what :func:`envelope.metrics` reads."""

    def __init__(self, t, **truth):
        self.t = t
        n = len(t)
        base = {k: np.zeros(n) for k in ("beta", "ay", "x", "y", "yaw")}
        base.update(truth)
        self.truth = base
        self.commands = {"steer": np.zeros(n), "steer_cmd": np.zeros(n), "steer_driver": np.zeros(n),
                         "yaw_moment_cmd": np.zeros(n),
                         "yaw_moment": np.zeros(n)}


def test_crosswind_deviation_is_read_2_s_after_the_gust():
    # drift y = 0.5 a (t - 2)^2 from the gust at 2 s: 2 a at 4 s (2.42 a at 4.2 s, 1.62 a at 3.8 s)
    t = np.arange(0.0, 6.0, 1e-3)
    a = 0.3
    y = np.where(t > 2.0, 0.5 * a * (t - 2.0) ** 2, 0.0)
    man = dataclasses.replace(step_steer(27.0, 0.0, duration=6.0), events={"gust": 2.0})
    met = ev.metrics(_Run(t, y=y), man, load_vehicle("compact-ev"))
    assert met.deviation_m == pytest.approx(2 * a, abs=1e-6)  # interpolation of a parabola at a sample


def test_cones_inside_the_body_outline():
    # the car straight along x at y = 0, yaw 0, its CG from x = -20 to 20 m: a cone just inside half
    # the width is hit, just outside not; along the car, the outline ends lf + 0.8 m ahead of the CG
    p = load_vehicle("compact-ev")
    x = np.linspace(-20.0, 20.0, 4001)
    z = np.zeros_like(x)
    w = 1.8
    assert ev.cones_hit(x, z, z, np.array([[0.0, 0.89]]), p, w) == 1
    assert ev.cones_hit(x, z, z, np.array([[0.0, 0.91]]), p, w) == 0
    assert ev.cones_hit(x, z, z, np.array([[0.0, -0.89], [0.0, -0.91], [5.0, 0.0]]), p, w) == 2
    # the car stops with its CG at x = 0: a cone 0.79 m beyond the front axle touches, 0.81 m does not
    stop = np.linspace(-20.0, 0.0, 2001)
    zs = np.zeros_like(stop)
    assert ev.cones_hit(stop, zs, zs, np.array([[p.lf + 0.79, 0.0]]), p, w) == 1
    assert ev.cones_hit(stop, zs, zs, np.array([[p.lf + 0.81, 0.0]]), p, w) == 0
    # and behind: the car starts with its CG at x = 0
    assert ev.cones_hit(-stop, zs, zs, np.array([[-(p.lr + 0.79), 0.0]]), p, w) == 1
    assert ev.cones_hit(-stop, zs, zs, np.array([[-(p.lr + 0.81), 0.0]]), p, w) == 0
    # turned 90 deg (yaw pi/2), half the width lies along x
    up = np.full_like(x, np.pi / 2)
    assert ev.cones_hit(z, x, up, np.array([[0.89, 0.0]]), p, w) == 1
    assert ev.cones_hit(z, x, up, np.array([[0.91, 0.0]]), p, w) == 0


def test_iso3888_2_lanes():
    # ISO 3888-2 for a 1.8 m car: 12 / 13.5 / 11 / 12.5 / 12 m; lanes 1.1 w + 0.25 = 2.23 m,
    # w + 1 = 2.8 m and 1.3 w + 0.25 = 2.59 m -> at least 3 m; lane 3 starts 1 m left of lane 1
    g = iso3888_2_lanes(1.8)
    assert [b - a for a, b in g["sections"]] == pytest.approx([12.0, 13.5, 11.0, 12.5, 12.0])
    assert g["widths"] == pytest.approx((2.23, 2.8, 3.0))
    assert g["lane1"] == pytest.approx((-1.115, 1.115))
    assert g["lane3"] == pytest.approx((2.115, 4.915))
    assert g["lane5"] == pytest.approx((-1.115, 1.885))
    man = iso3888_2(60 / 3.6, 1.8)
    assert len(man.cones) == 18 and man.coast_from == pytest.approx(40.0 / (60 / 3.6))
    # the planned line is in lane 3's centre through section 3
    ys = np.interp([25.5, 31.0, 36.5], man.path.x, man.path.y)
    assert ys == pytest.approx([3.515] * 3, abs=1e-9)


def test_slalom_line():
    # A = w/2 + 0.2 m; the line passes cone k at y = -A cos(pi k) (alternate sides) with peak lateral
    # acceleration A (pi v / 18)^2 = 6.47 m/s^2 for a 1.8 m car at 50 km/h
    man = slalom(50 / 3.6, 1.8)
    amp = 1.1
    assert man.events["amplitude"] == pytest.approx(amp)
    ys = np.interp(18.0 * np.arange(7), man.path.x, man.path.y)
    assert ys == pytest.approx(-amp * np.cos(np.pi * np.arange(7)), abs=1e-9)
    assert amp * (np.pi * 50 / 3.6 / 18.0) ** 2 == pytest.approx(6.47, abs=0.01)


def test_loaded_car():
    # 150 kg 0.5 m behind the rear axle of compact-ev: the CG moves back by 150 (lr + 0.5) / (m + 150),
    # the yaw inertia grows by the parallel-axis terms, the rear stiffness with the rear axle load
    p = load_vehicle("compact-ev")
    q = ev.loaded(p)
    m0 = p.mass
    shift = 150.0 * (p.lr + 0.5) / (m0 + 150.0)
    assert q.mass == m0 + 150.0
    assert q.lf == pytest.approx(p.lf + shift) and q.lr == pytest.approx(p.lr - shift)
    iz = p.yaw_inertia + m0 * shift ** 2 + 150.0 * (p.lr + 0.5 - shift) ** 2
    assert q.yaw_inertia == pytest.approx(iz)
    rear0, rear = m0 * p.lf / p.wheelbase, (m0 + 150.0) * q.lf / p.wheelbase
    assert q.cornering_stiffness_rear == pytest.approx(p.cornering_stiffness_rear * rear / rear0)
    # the static rear axle load grows by 150 x (L + 0.5) / L (the lever about the front axle)
    assert (rear - rear0) == pytest.approx(150.0 * (p.wheelbase + 0.5) / p.wheelbase)


def test_human_driver_reacts_after_the_delay_and_through_the_lag():
    # a car at rest 0.2 m left of a straight path: the driver wants -atan(1.5 x 0.2 / (0 + 1 m/s))
    # (Stanley's correction; nothing moves, so his prediction is the present), which reaches the road
    # wheels after the reaction delay (0.15 s) through the neuromuscular lag (0.1 s): 1 - 0.99^n of it
    # n ms later (the lag at 1 ms steps)
    p = load_vehicle("compact-ev")
    path = Path(np.linspace(-10.0, 200.0, 841), np.full(841, -0.2))
    drv = HumanDriver(path, p, 1e-3)
    st = drv.initial_state()
    out = []
    for _ in range(600):
        st, u = drv.steer(st, 0.0, 0.0, 0.0, 0.0)
        out.append(u)
    out = np.array(out)
    target = -np.arctan(1.5 * 0.2)  # right: negative steer (ISO 8855)
    assert np.all(out[:150] == 0.0)
    n = np.arange(1, 451)
    assert out[150:] == pytest.approx(target * (1 - 0.99 ** n), rel=1e-9)


def test_the_ecu_takes_the_drive_torque_away_while_it_acts():
    # the friction drop (mu 1 -> 0.3 in a steady turn at 80 km/h): the driver's speed hold drives the rear
    # motors, and their drive force uses the grip the rear axle needs against the slide. The ECU lets
    # 1 - drive_cut x its authority of the drive through (all of it wherever the law is off); with the default
    # cut (0.5) the car slides less than without it (measured 3.65 against 4.03 deg, seed 0)
    from evstab.controllers.two_dof import TwoDofDesign
    from evstab.toolkit.loop.simulator import simulate
    p = load_vehicle("compact-ev")
    assert TwoDofDesign(p).drive_cut == 0.5
    case = next(c for c in ev.cases("two-track") if c.label == "friction-drop 80 km/h mu 1 -> 0.3")
    man, road, _ = ev.run_setup(case, p)
    runs = {cut: simulate(p, "two-track", man, disturbances=road, controller="two-dof",
                          design=TwoDofDesign(p, drive_cut=cut)) for cut in (0.0, 0.5)}
    cut, kept = runs[0.5], runs[0.0]
    assert np.all(kept["drive_share"] == 1.0)
    off = cut["active"] == 0.0
    assert off.any() and (~off).any()
    assert np.all(cut["drive_share"][off] == 1.0)
    # where cut, 1 - 0.5 x active (the oversteer latch set), to the last bit of the product and the subtraction
    # (1 ulp at 1); elsewhere all of it (the latch clear); and the slide sets the latch at full authority
    ds, share = cut["drive_share"], 1.0 - 0.5 * cut["active"]
    latched = np.abs(ds - share) <= 2.3e-16
    assert np.all(latched | (ds == 1.0))
    assert np.any(latched & (ds == 0.5))
    peak = {k: np.degrees(np.max(np.abs(r["beta"]))) for k, r in runs.items()}
    # 0.2 deg: the cut's effect, measured 0.38 deg, against a rounding-level difference were it not there
    assert peak[0.5] < peak[0.0] - 0.2, peak


def test_the_whole_drive_cut_loses_a_held_limit_turn():
    # the envelope's held step at 100 km/h on mu 0.5 (held 8 s), seed 4, with the reference's headroom at 1.25 m/s^2
    # (a reference that asks less at the turn-in, so that the law acts longer): with the whole drive cut the car
    # slows in the turn, load moves to the front axle and the rear drifts out past the stabilise rule's 5 deg
    # (measured 15.9 deg); with half of it the car is held (1.96 deg), and with the default headroom too (2.05 deg,
    # where the whole cut holds 2.06 as well). The car alone spins.
    from evstab.controllers.two_dof import TwoDofDesign
    p = load_vehicle("compact-ev")
    case = next(c for c in ev.cases("two-track") if c.label == "held-step 100 km/h mu 0.5")
    whole = ev.run(case, p, "two-track", seed=4, design=TwoDofDesign(p.as_nominal(), drive_cut=1.0, ay_headroom=1.25))
    half = ev.run(case, p, "two-track", seed=4, design=TwoDofDesign(p.as_nominal(), ay_headroom=1.25))
    design = TwoDofDesign(p.as_nominal())
    assert design.drive_cut == 0.5
    default = ev.run(case, p, "two-track", seed=4, design=design)
    assert max(half.peak_beta_deg, default.peak_beta_deg) < ev.HELD_DEG < whole.peak_beta_deg
