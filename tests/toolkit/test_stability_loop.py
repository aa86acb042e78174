"""The stability analysis linearises the loop step itself (casadi Jacobians over a GPS period).

The frozen values are the eigenvalues of the closed-form construction of the same sampled loop
(linear bicycle by matrix exponential, ZOH; Kalman filter with the periodic Riccati gains of
``toolkit.estimation.analysis.periodic_gains``; the 2-DOF law's matrices; the heading removed by
``psi_hat - psi``), computed before that hand-built construction was removed. The Jacobian
monodromy equalled it to 4.2e-12 on every bundled vehicle with motors (dakf, kf, kf-bias;
seed 003 gains and K_beta 12 / K_gamma 3 with -30 % front stiffness and +10 % mass; 5 Hz, 1 Hz and
single-rate GPS).
"""

import dataclasses

import numpy as np
import pytest

from evstab.controllers.schedule import SpeedSchedule
from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
from evstab.toolkit.estimation import design_filter
from evstab.toolkit.design import stability as st

GOLDEN = {
    ("compact-ev", "dakf", 5.0, 5.0, False, 5.0): [
        (0.9930537803986643, -0.0061812069033264), (0.9930537803986643, 0.0061812069033264),
        (0.8778903094839143, 0.0), (0.3654992262320947, -0.0006208027209287),
        (0.3654992262320947, 0.0006208027209287), (0.0820596538417787, -0.1734522935724607),
        (0.0820596538417787, 0.1734522935724607), (0.113582768257606, -0.1332117147339754),
        (0.113582768257606, 0.1332117147339754), (0.0, 0.0)],
    ("commonroad-1", "kf-bias", 12.0, 3.0, True, 1.0): [
        (0.8631833808293267, -0.1146556804935141), (0.8631833808293267, 0.1146556804935141),
        (0.0811911533510181, 0.0), (0.0001260679373267, 0.0), (-7.386731585e-07, -1.322691433e-07),
        (-7.386731585e-07, 1.322691433e-07), (8.7659906e-08, 0.0), (0.0, 0.0)],
    ("commonroad-1", "dakf", 12.0, 3.0, True, None): [
        (1.000053744870078, 0.0), (0.9999786266752669, 0.0), (0.999629601711827, 0.0),
        (0.9975668191352484, 0.0), (0.9908962265642332, 0.0), (0.9896667233389728, -0.0142730895671015),
        (0.9896667233389728, 0.0142730895671015), (0.9786874765453268, 0.0), (0.9482901559134637, 0.0),
        (0.3176822201894191, 0.0)],
}


def _case(vehicle, kb, kg, error):
    p = load_vehicle(vehicle)
    nom = p.as_nominal()
    v = 1.0 / SpeedSchedule.build(nom).inv_speed[12]  # a grid speed: the ECU's tables are exact there
    true = dataclasses.replace(nom, cornering_stiffness_front=0.7 * nom.cornering_stiffness_front,
                               mass=1.1 * p.mass) if error else None
    return p, TwoDofDesign(nom, k_beta=kb, k_gamma=kg), v, true


@pytest.mark.parametrize("key", list(GOLDEN))
def test_jacobian_monodromy_equals_the_frozen_closed_form(key):
    vehicle, method, kb, kg, error, rate = key
    p, d, v, true = _case(vehicle, kb, kg, error)
    lin = st.loop_linearisation(d, design_filter(method, p, control=True), v, true_params=true, gps_rate=rate)
    eig = np.linalg.eigvals(lin.monodromy)
    gold = np.array([complex(*c) for c in GOLDEN[key]])
    for g in gold:  # 1e-9: the bound; measured 4e-12 (rounding through 1000 sample products)
        assert np.min(np.abs(eig - g)) < 1e-9, (g, eig)
    # the loop state has more entries than the closed form (applied commands, actuator states):
    # one-sample delays, whose eigenvalues are 0 (to rounding: 1e-15 measured)
    matched = {int(np.argmin(np.abs(eig - g))) for g in gold}
    assert all(abs(eig[i]) < 1e-9 for i in range(len(eig)) if i not in matched)
    # what the analysis kept: the bicycle's sideslip and yaw rate, every filter state, the integrators
    assert {"plant.beta", "plant.yaw_rate", "controller.xi_beta", "controller.xi_yaw_rate"} <= set(lin.core)
    assert "plant.yaw" not in lin.core and "plant.x" not in lin.core


@pytest.mark.parametrize("unstable", [False, True])
def test_monodromy_agrees_with_the_loop_run_in_time(unstable):
    # the linearisation against the loop itself: the compiled rollout of the same loop from a small
    # perturbation of straight running, compared block by block (5 GPS periods) with the monodromy
    p = load_vehicle("compact-ev")
    plant = dataclasses.replace(p, cornering_stiffness_rear=0.3 * p.cornering_stiffness_rear) if unstable else p
    d = TwoDofDesign(plant.as_nominal())
    est = design_filter("kf-bias", p)
    _, stab = st.estimator_loop(d, est, 20.0, true_params=plant, gps_rate=5.0)
    lin = st.loop_linearisation(d, est, 20.0, true_params=plant, gps_rate=5.0)
    prog, z_eq, U1, pv, theta = st.equilibrium(d, est, 20.0, true_params=plant, gps_rate=5.0)
    names = prog.spec.state_names()
    core = [names.index(n) for n in lin.core]
    i_yaw_hat, ipsi = names.index("filter.yaw"), names.index("plant.yaw")
    U = np.tile(U1, (5, 1))  # 1000 samples = 5 GPS periods per block
    Phi5 = np.linalg.matrix_power(lin.monodromy, 5)
    eps = 1e-7
    x = np.random.default_rng(0).standard_normal(len(core))
    x *= eps / np.linalg.norm(x)
    ref = z_eq.copy()
    for _ in range(20):
        pert = ref.copy()
        pert[core] += x
        pert[i_yaw_hat] += pert[ipsi] - ref[ipsi]  # the reduced coordinate is yaw_hat - psi
        _, _, ref_n = prog.run(U, ref, pv, theta, final_state=True)
        _, _, pert_n = prog.run(U, pert, pv, theta, final_state=True)
        diff = pert_n - ref_n
        diff[i_yaw_hat] -= diff[ipsi]
        # the loop is linear to O(eps) about straight running and the product of 1000 Jacobians is
        # rounding-accurate: measured 5e-14 (stable) and 2e-10 (unstable car) of the deviation; 1e-8
        np.testing.assert_allclose(diff[core], Phi5 @ x, rtol=0, atol=1e-8 * np.linalg.norm(Phi5 @ x))
        x = diff[core] * (eps / np.linalg.norm(diff[core]))
        ref = ref_n
    # and the spectral radius is the growth of the monodromy's power iteration (3000 blocks: the
    # dominant pair is complex and non-normal, ~log(cond) / 15000 periods = 0.1 %)
    y, logs = np.ones(len(core)), []
    for _ in range(3000):
        y = Phi5 @ y
        logs.append(np.log(np.linalg.norm(y)))
        y /= np.linalg.norm(y)
    rho = float(np.max(np.abs(stab.poles)))
    assert np.exp(np.mean(logs) / 5.0) == pytest.approx(rho, rel=2e-3)
    assert (rho > 1) == unstable and stab.stable == (not unstable)


def test_excessive_gain_is_unstable_in_the_sampled_loop():
    p = load_vehicle("compact-ev")
    est = design_filter("dakf", p, control=True)
    assert st.estimator_loop(TwoDofDesign(p.as_nominal()), est, 20.0, gps_rate=5.0)[1].stable
    # K dt = 4 > 2: the sampled proportional path overshoots every sample
    assert not st.estimator_loop(TwoDofDesign(p.as_nominal(), k_beta=4000, k_gamma=4000), est, 20.0,
                                 gps_rate=5.0)[1].stable
