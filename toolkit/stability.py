"""Stability of the loop: python-control for the continuous and single-rate loops,
the lifted (monodromy) matrix for the multi-rate loop python-control cannot build.

Everything returns data (:class:`LoopStability`); nothing prints.

* :func:`nominal_loop` — the 2-DOF controller's feedback on a linear bicycle plant
  (true parameters may differ from the controller's nominal ones), interconnected
  with ``control.interconnect`` with signals injected at the plant input (``du``)
  and output (``dy``). The loop is internally stable iff every map from
  ``(r, du, dy)`` to ``(u, y, e)`` is stable; with minimal realisations of plant and
  controller that is iff the interconnection's A matrix is Hurwitz.
* :func:`estimator_loop` — the discrete loop at the control period with the
  estimator in it: true plant (ZOH), Kalman filter with its steady-state (single
  rate) or periodic (multi-rate) gains, controller using the estimates including
  the disturbance-rejection term. The multi-rate loop is analysed through its
  monodromy matrix over one GPS period (the product of the per-sample closed-loop
  transition matrices); the loop is stable iff its spectral radius is below 1.
  The true heading is a pure integrator that feeds nothing (the filter sees it
  only through ``psi_hat - psi``); it is removed by that change of coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np
import scipy.linalg

from controllers.two_dof import TwoDofDesign
from plants import VehicleParams
from plants.bicycle import lateral_matrices

from .estimation.analysis import periodic_gains, steady_state_gain
from .estimation.kalman import discretize
from .estimation.spec import FilterDesign, continuous_model
from plants.backend import NUMPY


@dataclass(frozen=True)
class LoopStability:
    poles: np.ndarray
    """Continuous poles [1/s], or discrete eigenvalues (per sample / per GPS period)."""
    stable: bool
    margin: float
    """Continuous: -max Re(pole) [1/s] (> 0 stable). Discrete: 1 - spectral radius (> 0 stable)."""
    kind: str


def controller_ss(design: TwoDofDesign, speed: float) -> control.StateSpace:
    """The feedback part ``C_fb`` as a named python-control system: e -> u (PI realisation)."""
    Bi, Kp, Ki, _ = design.gains(speed)
    return control.ss(np.zeros((2, 2)), np.eye(2), Ki, Kp, inputs=["e_beta", "e_r"], outputs=["u_delta", "u_Nz"],
                      states=["xi_beta", "xi_r"], name="C")


def plant_ss(true_params: VehicleParams, speed: float) -> control.StateSpace:
    A, B = lateral_matrices(true_params, speed)
    return control.ss(A, B, np.eye(2), np.zeros((2, 2)), inputs=["delta", "Nz"], outputs=["beta", "r"],
                      states=["beta", "r"], name="P")


def nominal_loop(design: TwoDofDesign, speed: float, true_params: VehicleParams | None = None,
                 controller_speed: float | None = None):
    """Interconnected loop (python-control) and its internal stability.

    ``true_params`` is the plant the controller meets (model error); ``controller_speed``
    the speed the controller is scheduled at when it differs from the true ``speed``.
    """
    P = plant_ss(true_params or design.params, speed)
    C = controller_ss(design, speed if controller_speed is None else controller_speed)
    e_blk = control.ss([], [], [], np.hstack([np.eye(2), -np.eye(2)]), inputs=["r_beta", "r_r", "y_beta", "y_r"],
                       outputs=["e_beta", "e_r"], name="err")
    u_blk = control.ss([], [], [], np.hstack([np.eye(2), np.eye(2)]), inputs=["u_delta", "u_Nz", "du_delta", "du_Nz"],
                       outputs=["delta", "Nz"], name="uin")
    y_blk = control.ss([], [], [], np.hstack([np.eye(2), np.eye(2)]), inputs=["beta", "r", "dy_beta", "dy_r"],
                       outputs=["y_beta", "y_r"], name="yout")
    loop = control.interconnect(
        [P, C, e_blk, u_blk, y_blk],
        inputs=["r_beta", "r_r", "du_delta", "du_Nz", "dy_beta", "dy_r"],
        outputs=["u_delta", "u_Nz", "y_beta", "y_r", "e_beta", "e_r"], name="loop")
    poles = np.linalg.eigvals(loop.A)
    margin = float(-np.max(poles.real))
    return loop, LoopStability(np.sort_complex(poles), bool(margin > 0), margin, "continuous")


def _closed_loop_matrices(design: TwoDofDesign, est: FilterDesign, true_params: VehicleParams, speed: float,
                          gains: list, dt: float):
    """Per-sample transition matrices of (beta, r, psi, x_hat, xi) for the given update gains."""
    A, B = lateral_matrices(true_params, speed)
    A3 = np.zeros((3, 3))
    A3[:2, :2] = A
    A3[2, 1] = 1.0
    B3 = np.vstack([B, np.zeros((1, 2))])
    blk = scipy.linalg.expm(np.block([[A3, B3], [np.zeros((2, 5))]]) * dt)
    Ap, Bp = blk[:3, :3], blk[:3, 3:]
    Ae, Be = continuous_model(est, speed, NUMPY)
    F, Gam = discretize(Ae, dt, NUMPY, est.n)
    G = Gam @ Be
    n = est.n
    ib, ir, iy = est.index("beta"), est.index("yaw_rate"), est.index("yaw")
    S = np.zeros((2, n))
    S[0, ib], S[1, ir] = 1.0, 1.0
    Sd = np.zeros((2, n))
    if "d1" in est.states and design.disturbance_rejection:
        Sd[0, est.index("d1")], Sd[1, est.index("d2")] = 1.0, 1.0
    Bi, Kp, Ki, _ = design.gains(speed)
    # u_k = -(Kp S + Bi Sd) x_hat + Ki xi
    Ku_x = -(Kp @ S + Bi @ Sd)
    Ku_xi = Ki
    # measurements of the truth (gyro r, course beta + psi) and of the model
    Ct = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 1.0]])
    H = np.zeros((2, n))
    H[0, ir] = 1.0
    if est.bias:
        H[0, est.index("gyro_bias")] = 1.0
    H[1, ib], H[1, iy] = 1.0, 1.0
    mats = []
    N = 3 + n + 2
    for K in gains:
        m = K.shape[1]
        M = np.zeros((N, N))
        # u in terms of the state
        U = np.zeros((2, N))
        U[:, 3:3 + n] = Ku_x
        U[:, 3 + n:] = Ku_xi
        X1 = np.zeros((3, N))
        X1[:, :3] = Ap
        X1 += Bp @ U
        Xm = np.zeros((n, N))
        Xm[:, 3:3 + n] = F
        Xm += G @ U
        Xh = Xm + K @ (Ct[:m] @ X1 - H[:m] @ Xm)
        XI = np.zeros((2, N))
        XI[:, 3 + n:] = np.eye(2)
        XI[:, 3:3 + n] -= dt * S
        M[:3], M[3:3 + n], M[3 + n:] = X1, Xh, XI
        mats.append(M)
    # change of coordinates psi_hat -> psi_hat - psi, then drop the true heading
    T = np.eye(N)
    T[3 + iy, 2] = -1.0
    Ti = np.linalg.inv(T)
    keep = [i for i in range(N) if i != 2]
    return [(T @ M @ Ti)[np.ix_(keep, keep)] for M in mats]


def estimator_loop(design: TwoDofDesign, est: FilterDesign, speed: float, *, true_params: VehicleParams | None = None,
                   gps_rate: float | None = None, dt: float = 1e-3):
    """Discrete loop with the estimator: single rate (``gps_rate=None``) or multi-rate monodromy."""
    true_params = true_params or design.params
    if gps_rate is None:
        K, P = steady_state_gain(est, speed, dt)
        mats = _closed_loop_matrices(design, est, true_params, speed, [K], dt)
        eig = np.linalg.eigvals(mats[0])
        kind = "discrete single-rate (per sample)"
    else:
        gains, _ = periodic_gains(est, speed, gps_rate, dt)
        mats = _closed_loop_matrices(design, est, true_params, speed, gains, dt)
        Phi = np.eye(mats[0].shape[0])
        for M in mats:
            Phi = M @ Phi
        eig = np.linalg.eigvals(Phi)
        kind = f"multi-rate monodromy over one GPS period ({len(mats)} samples)"
        mats = [Phi]
    rho = float(np.max(np.abs(eig)))
    return mats, LoopStability(eig, bool(rho < 1.0), 1.0 - rho, kind)


@dataclass(frozen=True)
class ChannelMargins:
    """Loop-at-a-time margins of one channel (the others closed)."""

    channel: str
    gm_db: float
    """Gain margin [dB] (inf when the phase never crosses -180 deg)."""
    pm_deg: float
    """Phase margin [deg]."""
    crossover_rad_s: float
    """Gain crossover frequency [rad/s] (nan without a crossover)."""
    disk_margin: float
    """Balanced disk margin alpha (skew 0) [-]: simultaneous gain and phase variation tolerated."""
    sensitivity_peak: float
    """max |1 / (1 + L)| over frequency [-]."""


def _return_ratio(T: control.StateSpace) -> control.StateSpace:
    """``L = -T / (1 + T)`` from a channel's closed-loop map ``T``, where ``x = T d`` and ``x = -L (x + d)``."""
    return control.feedback(-T, -1)


def _gain_margin_db(resp: np.ndarray) -> float:
    """Gain margin [dB] from a frequency response: at each -180 deg phase crossing (where
    ``Im L`` changes sign with ``Re L < 0``), ``-20 log10 |L|``; the smallest in magnitude.
    Crossings where ``|L|`` is below 1e-6 or above 1e6 are round-off of a realisation
    whose phase only grazes -180 deg, and are ignored; none left: inf."""
    im = np.imag(resp)
    k = np.nonzero((np.sign(im[:-1]) != np.sign(im[1:])) & (np.real(resp[:-1]) < 0))[0]
    margins = []
    for i in k:
        f = im[i] / (im[i] - im[i + 1])
        mag = abs(resp[i] + f * (resp[i + 1] - resp[i]))
        if 1e-6 < mag < 1e6:
            margins.append(-20.0 * np.log10(mag))
    return float(min(margins, key=abs)) if margins else float("inf")


def channel_margins(loop: control.InterconnectedSystem, omega: np.ndarray | None = None) -> list[ChannelMargins]:
    """Loop-at-a-time margins at the plant inputs (``delta``, ``Nz``) and outputs (``beta``, ``r``).

    Each channel of :func:`nominal_loop`'s loop is broken where its signal is
    injected, the other channel staying closed. At an input, the controller output
    answers an injection ``du`` with ``u = T du``, ``u = -L (u + du)``; at an output the
    measured signal is ``y = S dy`` with ``S = 1 / (1 + L)``, i.e. ``T = S - 1`` in the
    same form. Disk margins are python-control's balanced (skew 0) ones.
    """
    omega = np.logspace(-2, 3, 1500) if omega is None else omega
    out = []
    for name, inj, sig, at_output in (("delta", "du_delta", "u_delta", False), ("Nz", "du_Nz", "u_Nz", False),
                                      ("beta", "dy_beta", "y_beta", True), ("r", "dy_r", "y_r", True)):
        T = loop[sig, inj]
        if at_output:
            T = T - 1.0
        L = _return_ratio(T)
        _, pm, _, _, wgc, _ = control.stability_margins(L)
        resp = np.squeeze(L(1j * omega))
        S = 1.0 / (1.0 + resp)
        dm = float(np.min(np.asarray(control.disk_margins(L, omega, skew=0.0)[0]).ravel()))
        gm_db = _gain_margin_db(resp)
        out.append(ChannelMargins(name, gm_db, float(pm), float(wgc) if np.isfinite(wgc) else float("nan"),
                                  dm, float(np.max(np.abs(S)))))
    return out
