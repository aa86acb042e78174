"""Vehicle parameter sets: loading, validation, derived values, error messages."""

import dataclasses
import math

import pytest

from evstab.plants import G, ParameterError, VehicleParams, bundled_vehicles, load_vehicle

BASE = """
[meta]
name = "t"
source = "test"

[vehicle]
mass = 1500.0
yaw_inertia = 2500.0
lf = 1.2
lr = 1.4
cornering_stiffness_front = 40000
cornering_stiffness_rear = 45000
"""


def write(tmp_path, text, name="car.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_bundled_names():
    assert set(bundled_vehicles()) == {"micro-ev", "sedan-000", "compact-ev", "commonroad-1", "commonroad-2",
                                       "commonroad-3"}


def test_every_bundled_set_cites_a_source(vehicle):
    assert len(vehicle.source) > 20


def test_sedan_matches_seed_000_table_1():
    p = load_vehicle("sedan-000")
    # Values as printed in seed 000 Table 1 (exact: they are copied, not computed).
    assert (p.mass, p.sprung_mass, p.lf, p.lr) == (1704.7, 152.6, 1.035, 1.655)
    assert (p.track_front, p.track_rear, p.cg_height) == (1.535, 1.535, 0.542)
    assert (p.roll_inertia, p.yaw_inertia, p.wheel_inertia, p.wheel_radius) == (744.0, 3048.1, 0.99, 0.313)
    assert p.roll_stiffness == 47298 + 37311 and p.roll_damping == 2823 + 2653
    assert p.cornering_stiffness_front == p.cornering_stiffness_rear == 55095
    assert p.frontal_area == 1.8


def test_micro_ev_true_and_nominal_stiffness():
    p = load_vehicle("micro-ev")
    assert p.cornering_stiffness_front == p.cornering_stiffness_rear == 7000.0  # seed 003 sec. VI
    n = p.as_nominal()
    assert n.cornering_stiffness_front == n.cornering_stiffness_rear == 10000.0
    assert n.mass == p.mass


def test_derived_values_closed_form():
    p = VehicleParams(name="t", mass=1500, yaw_inertia=2500, lf=1.2, lr=1.4,
                      cornering_stiffness_front=40000, cornering_stiffness_rear=45000)
    L = 2.6
    assert p.wheelbase == pytest.approx(L, rel=1e-15)
    assert p.static_axle_load_front + p.static_axle_load_rear == pytest.approx(1500 * G, rel=1e-14)
    assert p.static_axle_load_front == pytest.approx(1500 * G * 1.4 / L, rel=1e-14)
    # K_us = M/L (lr/(2Cf) - lf/(2Cr)) by hand: 1500/2.6*(1.4/80000 - 1.2/90000)
    kus = 1500 / 2.6 * (1.4 / 80000 - 1.2 / 90000)
    assert p.understeer_gradient == pytest.approx(kus, rel=1e-13)  # rounding only
    assert p.characteristic_speed == pytest.approx(math.sqrt(L / kus), rel=1e-13)
    assert p.critical_speed == math.inf
    over = dataclasses.replace(p, lf=1.6, lr=1.0)
    assert over.understeer_gradient < 0 and math.isfinite(over.critical_speed)
    assert over.characteristic_speed == math.inf


def test_rollover_threshold_hand_worked():
    # Rigid car: the static stability factor g t / (2 h); t = 1.5 m, h = 0.5 m -> 1.5 g.
    base = dict(name="t", mass=1500, yaw_inertia=2500, lf=1.2, lr=1.4, cornering_stiffness_front=40000,
                cornering_stiffness_rear=45000, cg_height=0.5, track_front=1.4, track_rear=1.6)
    rigid = VehicleParams(**base)
    assert rigid.roll_gradient is None
    assert rigid.rollover_threshold == pytest.approx(1.5 * G, rel=1e-14)  # rounding only
    # Suspended body, m_s = 1000 kg, h_s = 0.5 m, K = 2 m_s g h_s: the body rolls 1 rad per g
    # (phi / a_y = m_s h_s / (K - m_s g h_s) = 1 / g), its shift adds m_s g h_s / g = 500 kg m to the
    # overturning moment arm m h = 750 kg m: a_y = 1500 g 1.5 / (2 (750 + 500)) = 0.9 g.
    body = VehicleParams(**base, sprung_mass=1000, roll_arm=0.5, roll_stiffness=2 * 1000 * G * 0.5)
    assert body.roll_gradient == pytest.approx(1.0 / G, rel=1e-14)
    assert body.rollover_threshold == pytest.approx(0.9 * G, rel=1e-14)
    # no CG height or track: no threshold
    assert VehicleParams(**{**base, "cg_height": None}).rollover_threshold is None


def test_a_suspension_that_cannot_hold_the_body_is_refused():
    # K must exceed the rolled body's gravity moment m_s g h_s = 1000 x 9.81 x 0.5 = 4905 N m/rad
    base = dict(name="t", mass=1500, yaw_inertia=2500, lf=1.2, lr=1.4, cornering_stiffness_front=40000,
                cornering_stiffness_rear=45000, sprung_mass=1000, roll_arm=0.5)
    VehicleParams(**base, roll_stiffness=1000 * G * 0.5 * 1.001)
    with pytest.raises(ParameterError, match="'roll_stiffness'.*gravity moment"):
        VehicleParams(**base, roll_stiffness=1000 * G * 0.5)


def test_frozen_and_keyword_only():
    p = load_vehicle("compact-ev")
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.mass = 1.0
    with pytest.raises(TypeError):
        VehicleParams(1500.0)  # positional arguments are refused


@pytest.mark.parametrize("field,value", [("mass", -1.0), ("yaw_inertia", 0.0), ("cornering_stiffness_rear", 0.0),
                                         ("mass", float("nan")), ("lf", -0.1)])
def test_bad_values_name_field_value_and_range(field, value):
    p = load_vehicle("compact-ev")
    with pytest.raises(ParameterError) as e:
        dataclasses.replace(p, **{field: value})
    msg = str(e.value)
    assert field in msg and ("range" in msg or "finite" in msg)


def test_lf_plus_lr_positive():
    p = load_vehicle("compact-ev")
    with pytest.raises(ParameterError, match="lf \\+ lr"):
        dataclasses.replace(p, lf=0.0, lr=0.0)


def test_unknown_key_names_key_and_file(tmp_path):
    f = write(tmp_path, BASE + "wheelbase_typo = 2.6\n")
    with pytest.raises(ParameterError) as e:
        load_vehicle(f)
    assert "wheelbase_typo" in str(e.value) and str(f) in str(e.value)


def test_missing_key_names_key_and_file(tmp_path):
    f = write(tmp_path, BASE.replace("yaw_inertia = 2500.0\n", ""))
    with pytest.raises(ParameterError) as e:
        load_vehicle(f)
    assert "'yaw_inertia'" in str(e.value) and str(f) in str(e.value)


def test_negative_mass_in_file(tmp_path):
    f = write(tmp_path, BASE.replace("mass = 1500.0", "mass = -1500.0"))
    with pytest.raises(ParameterError) as e:
        load_vehicle(f)
    assert "'mass'" in str(e.value) and str(f) in str(e.value) and "-1500" in str(e.value)


@pytest.mark.parametrize("text,needle", [
    ("not toml [", "not valid TOML"),
    (BASE.replace('[meta]\nname = "t"\nsource = "test"\n', ""), "[meta]"),
    (BASE.replace('source = "test"\n', ""), "'source'"),
    (BASE + "[extra]\nx = 1\n", "unknown table"),
    (BASE.replace("mass = 1500.0", 'mass = "heavy"'), "must be a number"),
])
def test_malformed_files(tmp_path, text, needle):
    f = write(tmp_path, text)
    with pytest.raises(ParameterError) as e:
        load_vehicle(f)
    assert needle in str(e.value) and str(f) in str(e.value)


def test_unknown_name_lists_bundled():
    with pytest.raises(ParameterError) as e:
        load_vehicle("no-such-car")
    assert "micro-ev" in str(e.value)


def test_require_names_missing_fields():
    p = VehicleParams(name="min", mass=1500, yaw_inertia=2500, lf=1.2, lr=1.4,
                      cornering_stiffness_front=40000, cornering_stiffness_rear=45000)
    with pytest.raises(ParameterError, match="wheel_radius"):
        p.require("wheel_radius", model="two-track")


def test_bom_file_loads(tmp_path):
    f = tmp_path / "bom.toml"
    f.write_bytes(b"\xef\xbb\xbf" + BASE.encode())
    assert load_vehicle(f).mass == 1500.0
