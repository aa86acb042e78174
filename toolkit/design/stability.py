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
  estimator in it, linearised from the loop step itself
  (:func:`toolkit.loop.closed_loop.loop_step`: sensors, the ECU step with its filter and
  the 2-DOF law, actuators, the linear bicycle as the true plant): casadi's Jacobians
  of that step at straight running, multiplied over one GPS period, give the
  multi-rate monodromy (:func:`loop_linearisation`); the loop is stable iff its
  spectral radius is below 1. The true heading is a pure integrator that feeds
  nothing (the filter sees it only through ``psi_hat - psi``); it is removed by that
  change of coordinates. Equal to the closed-form ZOH/periodic-Kalman construction of
  the same loop to 4e-12 on the bundled vehicles (the frozen values in
  ``tests/toolkit/test_stability_loop.py``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import control
import numpy as np

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import VehicleParams
from evstab.plants.bicycle import lateral_matrices

from ..estimation.core import posterior
from ..estimation.kalman import layout as kalman_layout
from ..estimation.spec import FilterDesign


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


ANALYSIS_SUBSTEPS = 4
"""RK4 sub-steps of the linearised loop's plant: at 1 ms the bicycle's fastest modes (|lambda| dt ~ 0.05)
are then integrated to ~1e-14 per sample, so the monodromy over a GPS period is the exact
zero-order-hold one to ~1e-11 (one sub-step leaves ~1e-9)."""


@dataclass(frozen=True)
class LoopLinearisation:
    """The loop step's Jacobians over one GPS period at straight running, and what the analysis kept."""

    monodromy: np.ndarray
    """Product of the per-sample Jacobians over the feedback core (see :func:`loop_linearisation`), heading removed."""
    core: tuple[str, ...]
    """Names of the loop-state entries in the feedback core (the heading one removed)."""
    outside: np.ndarray
    """Eigenvalues of the loop states outside the feedback core (sources and sinks of the loop:
    reference lag, positions, unused GPS slots, logged copies)."""
    samples: int


def analysis_states(spec) -> list[int]:
    """Loop-state entries the linearisation keeps: all but the filter's covariance and bookkeeping
    (gating counter, residual-prediction memory, initialisation flag, bias monitor), which at an
    equilibrium with zero innovations have zero derivative with respect to the rest."""
    f = spec.ecu.design.filter
    return [i for i, n in enumerate(spec.state_names())
            if not (n.startswith("filter.") and n[7:] not in f.states and not n.startswith("filter.buf"))]


def _heading_entries(names: list[str]) -> list[int]:
    """Loop-state entries that carry a heading (a common rotation of the road leaves the loop unchanged)."""
    return [i for i, n in enumerate(names) if n in ("plant.yaw", "filter.yaw") or n.startswith("filter.buf")
            or n.endswith(".yaw") and n.startswith("slot")]


def _scc_of(S: np.ndarray, seed: int) -> list[int]:
    """Indices of the strongly connected component of the directed graph ``S[i, j]`` (j -> i) that holds ``seed``."""
    def reach(adj):
        seen, stack = {seed}, [seed]
        while stack:
            k = stack.pop()
            for j in np.nonzero(adj[:, k])[0]:
                if j not in seen:
                    seen.add(int(j))
                    stack.append(int(j))
        return seen
    fwd = reach(S)      # what seed influences
    bwd = reach(S.T)    # what influences seed
    return sorted(fwd & bwd)


def equilibrium(design: TwoDofDesign, est: FilterDesign, speed: float, *, true_params: VehicleParams | None = None,
                gps_rate: float | None = None, dt: float = 1e-3, ideal_actuators: bool = True):
    """Straight running of the loop on the linear bicycle, the point :func:`loop_linearisation` linearises at:
    ``(program, z, U, p, theta)`` with ``z`` the loop state at the start of a GPS period (the filter
    initialised, its covariance at the periodic orbit's last posterior), ``U`` one period of inputs
    (a fix on its first sample, no noise, no steer)."""
    from evstab.controllers.actuators import ActuatorLimits
    from evstab.plants import DISTURBANCES, get_plant
    from evstab.plants.sensors import SensorConfig
    from ..loop.closed_loop import INPUTS, latch_schedule_parts, loop_initial_state, loop_spec
    from ..loop.loop_program import program
    from ..estimation.analysis import discrete_model, periodic_gains, steady_state_gain

    true_params = true_params or design.params
    rate = 1.0 / dt if gps_rate is None else gps_rate
    r = int(round(1.0 / (rate * dt)))
    sensors = SensorConfig(gps_rate=rate, gps_hdop=1.0)  # the filter's course noise at HDOP 1, as designed
    limits = ActuatorLimits(steer_tau=dt, steer_rate_max=1e9, torque_rate_max=1e12) if ideal_actuators \
        else ActuatorLimits()
    # the loop with the law acting: the supervisor's dead bands would leave straight running uncontrolled,
    # and its yaw guard (a sign test on the yaw-rate error, not differentiable at zero error) is left out
    design = dataclasses.replace(design, always_active=True, guard_share=1e6)
    spec = loop_spec(design.params, plant="bicycle", controller="two-dof", estimator=est, sensors=sensors, dt=dt,
                     design=design, truth=true_params, n_sub=ANALYSIS_SUBSTEPS, limits=limits)
    prog = program(spec)
    model = get_plant("bicycle")
    w0 = DISTURBANCES.pack(lateral_force=0.0, yaw_moment_dist=0.0, roll_moment_dist=0.0, bank=0.0,
                           **{f"mu_{c}": true_params.mu for c in ("fl", "fr", "rl", "rr")})
    z = loop_initial_state(spec, model.initial_state(true_params, speed), true_params, speed, w0)
    f = spec.ecu.design.filter
    lay = kalman_layout(f)
    if gps_rate is None:
        _, P = steady_state_gain(f, speed, dt)  # a-priori
        _, _, C, R = discrete_model(f, speed, dt)
        P_post, _ = posterior(P, C, R)
    else:
        _, posts = periodic_gains(f, speed, rate, dt)
        P_post = posts[-1]
    z_ecu = z[spec.state_layout.slot("ecu")]  # a view: writing it fills z
    z_ecu[lay.slot("P")] = P_post.ravel(order="F")
    z_ecu[lay.index("init")] = 1.0
    # an ECU that has been running (the first period is a start, which restarts the law): its guard past
    # it, with the equilibrium's inputs as its last good values (straight running: all 0 but the speed)
    from ..ecu import guard as guard_mod
    z_guard = z_ecu[spec.ecu.guard_slice]  # a view
    z_guard[guard_mod.STATE.index("started")] = 1.0
    z_guard[guard_mod.STATE.index("last_speed")] = speed
    U = INPUTS.zeros(r)
    col = INPUTS.columns(U)  # views
    col["speed_ref"][:], col["drive_on"][:] = speed, 1.0
    col["disturbances"][:] = w0
    fix = np.zeros(r)
    fix[0] = 1.0
    col["fix"][:] = fix
    col["capture"][:], col["emit"][:] = latch_schedule_parts(fix, 0.0, dt)
    pv = np.array([float(getattr(true_params, k)) for k in spec.fields])
    return prog, z, U, pv, prog.theta(mu_assumed=true_params.mu)


def loop_linearisation(design: TwoDofDesign, est: FilterDesign, speed: float, *,
                       true_params: VehicleParams | None = None, gps_rate: float | None = None, dt: float = 1e-3,
                       ideal_actuators: bool = True) -> LoopLinearisation:
    """Linearise the stability loop (:func:`toolkit.loop.closed_loop.loop_step`, the ECU step in it) at
    straight running on the linear bicycle ``true_params`` at ``speed``.

    casadi differentiates the traced loop step; the per-sample Jacobians over one GPS period
    (``gps_rate`` None: a fix every sample, the single-rate loop) are evaluated along the
    equilibrium, where the filter's covariance runs on its periodic orbit (started from
    :func:`toolkit.estimation.analysis.periodic_gains`' posterior) and every innovation is zero.
    At that point the covariance, the gating and monitor states and the filter's bookkeeping
    have zero derivative with respect to the rest and are left out; of the rest the analysis keeps
    the feedback core, the strongly connected component of the Jacobians' graph that holds the
    plant's yaw rate (the other states are sources or sinks: their eigenvalues are
    :attr:`LoopLinearisation.outside`), and removes the heading, which the loop does not feel
    (a common rotation of plant, filter and GPS slots is an eigenvector with eigenvalue 1; the
    change of coordinates ``psi_hat - psi`` drops it). ``ideal_actuators``: the steer servo
    follows in one sample and no rate limit acts (the idealisation of the analysis; False
    keeps the loop's actuator lag). Below the controller's ``min_speed`` the ECU passes the driver
    through: no command depends on the car, and the core is the plant's own lateral modes.
    """
    prog, z, U, pv, theta = equilibrium(design, est, speed, true_params=true_params, gps_rate=gps_rate, dt=dt,
                                        ideal_actuators=ideal_actuators)
    spec = prog.spec
    jac = analysis_jacobian(spec)
    names = list(spec.state_names())
    r = U.shape[0]
    keep = analysis_states(spec)
    mats = []
    for k in range(r):
        mats.append(jac(z, U[k], pv, theta))
        z = prog.step_once(z, U[k], pv, theta)[0]
    graph = np.zeros(mats[0].shape, bool)
    for M in mats:
        graph |= M != 0.0
    kn = [names[i] for i in keep]
    core = _scc_of(graph, kn.index("plant.yaw_rate"))
    Phi = np.eye(len(kn))
    for M in mats:
        Phi = M @ Phi
    rest = [i for i in range(len(kn)) if i not in core]
    outside = np.linalg.eigvals(Phi[np.ix_(rest, rest)]) if rest else np.zeros(0)
    Pc = Phi[np.ix_(core, core)]
    cn = [kn[i] for i in core]
    if "plant.yaw" not in cn:  # below the controller's min_speed no command depends on the car: open loop
        return LoopLinearisation(Pc, tuple(cn), outside, r)
    # heading: z' = z - v psi on every heading entry (T), psi kept; Phi v = v makes psi's column e_psi
    ipsi = cn.index("plant.yaw")
    v = np.zeros(len(cn))
    v[_heading_entries(cn)] = 1.0
    e = np.eye(len(cn))[ipsi]
    T, Ti = np.eye(len(cn)) - np.outer(v - e, e), np.eye(len(cn)) + np.outer(v - e, e)
    red = [i for i in range(len(cn)) if i != ipsi]
    Pr = (T @ Pc @ Ti)[np.ix_(red, red)]
    return LoopLinearisation(Pr, tuple(cn[i] for i in red), outside, r)


_JAC: dict = {}


def analysis_jacobian(spec):
    """The loop step's Jacobian over :func:`analysis_states` for ``spec``, compiled (cached) when a
    compiler is there. At ``-Og``: the derivative code is large (93,417 instructions for compact-ev)
    and runs a few hundred times per analysis; ``-Og`` compiles it in about half the time of ``-O1``
    and a call runs as fast (measured: docs/internals.md, compiled kernels)."""
    from ..loop.closed_loop import traced
    spec = traced(spec)
    if spec not in _JAC:
        import ctypes
        from ..loop.loop_program import program
        from ..kernels.compiled import CFunction, cache_key, compile_library
        fn = program(spec).jacobian(analysis_states(spec))
        lib = compile_library([fn], cache_key("loopjac", spec), opt="-Og")
        if lib is not None:
            cf = CFunction(ctypes.CDLL(str(lib)), "loop_jac")
            n = fn.size1_out(0)
            def call(z, u, p, th, cf=cf, n=n):
                out = np.empty((n, n))
                cf([np.ascontiguousarray(z, float), np.ascontiguousarray(u, float), np.ascontiguousarray(p, float),
                    np.ascontiguousarray(th, float)], [out])
                return out.T  # column-major
            _JAC[spec] = call
        else:
            _JAC[spec] = lambda z, u, p, th, fn=fn: np.array(fn(z, u, p, th))
    return _JAC[spec]


def estimator_loop(design: TwoDofDesign, est: FilterDesign, speed: float, *, true_params: VehicleParams | None = None,
                   gps_rate: float | None = None, dt: float = 1e-3):
    """Discrete loop with the estimator: single rate (``gps_rate=None``) or multi-rate monodromy,
    from the loop step's Jacobians (:func:`loop_linearisation`). Returns ([monodromy], stability)."""
    lin = loop_linearisation(design, est, speed, true_params=true_params, gps_rate=gps_rate, dt=dt)
    eig = np.linalg.eigvals(lin.monodromy)
    kind = ("discrete single-rate (per sample)" if gps_rate is None
            else f"multi-rate monodromy over one GPS period ({lin.samples} samples)")
    rho = float(np.max(np.abs(eig)))
    return [lin.monodromy], LoopStability(eig, bool(rho < 1.0), 1.0 - rho, kind)


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


def frequency_response(sys: control.StateSpace, omega: np.ndarray) -> np.ndarray:
    """``C (j w I - A)^-1 B + D`` of a single-input single-output state-space system at the
    frequencies ``omega`` [rad/s], one batched solve (python-control's evaluation, 20 times faster)."""
    A, B, C, D = (np.asarray(m, float) for m in (sys.A, sys.B, sys.C, sys.D))
    n = A.shape[0]
    if n == 0:
        return np.full(len(omega), complex(D[0, 0]))
    M = (1j * np.asarray(omega, float))[:, None, None] * np.eye(n) - A
    X = np.linalg.solve(M, np.broadcast_to(B.astype(complex), (len(omega), n, B.shape[1])))
    return (C @ X)[:, 0, 0] + D[0, 0]


def disk_margin(resp: np.ndarray) -> float:
    """The balanced (skew 0) disk margin of a return ratio from its frequency response ``resp``:
    ``1 / max |S - 1/2|`` with ``S = 1 / (1 + L)`` (Seiler, Packard and Gahinet, "An Introduction to
    Disk Margins", IEEE Control Systems Magazine, 2020; python-control's ``disk_margins`` at skew 0)."""
    return float(1.0 / np.max(np.abs(1.0 / (1.0 + resp) - 0.5)))


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
        resp = frequency_response(L, omega)
        S = 1.0 / (1.0 + resp)
        dm = disk_margin(resp)
        gm_db = _gain_margin_db(resp)
        out.append(ChannelMargins(name, gm_db, float(pm), float(wgc) if np.isfinite(wgc) else float("nan"),
                                  dm, float(np.max(np.abs(S)))))
    return out


DISK_MARGIN_MIN = 0.5
"""The margin constraint the design report judges a design by: the balanced disk margin of every
loop-breaking point (the plant inputs delta, N_z and outputs beta, r), at every speed of the analysis
grid, on the design's own model, at least this [-] (the loop tolerates a gain change between x0.6 and
x1.67 together with a phase change of up to +-28 deg: ``(1 -+ a/2) / (1 +- a/2)`` and ``2 atan(a/2)``) ..."""
SENSITIVITY_PEAK_MAX = 2.0
"""... and the sensitivity peak there at most this [-] (6 dB) (:func:`margins_admissible`). The design
job's tuning holds its candidates to it (:class:`toolkit.design.tuning.MarginConstraint`), its selection checks
it, and the report's verdict states it with the margins across the sweep's model errors beside it
(``design.json`` ``sweep.margins``): those are reported, not constrained (the paper design's own least
disk margin there is 0.15, and in the full sweep a bound relative to it pins the tuning to the paper
design)."""


@dataclass(frozen=True)
class RobustMargins:
    """The worst loop-at-a-time margins of a controller over speeds and plants."""

    disk_margin: float
    sensitivity_peak: float
    gm_delta_db: float
    """Gain margin of the steer loop [dB], the smallest in magnitude (negative: a gain reduction)."""
    pm_delta_deg: float
    gm_nz_db: float
    pm_nz_deg: float
    where_disk: str
    """Where the disk margin is least (plant and speed)."""
    where_sensitivity: str

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def robust_margins(ctl: TwoDofDesign, plants: list[tuple[str, VehicleParams]], speeds_kmh) -> RobustMargins:
    """The worst of :func:`channel_margins` over ``plants`` (label, true parameters) and ``speeds_kmh``."""
    dm, sp = (float("inf"), ""), (0.0, "")
    gm = {"delta": float("inf"), "Nz": float("inf")}
    pm = {"delta": float("inf"), "Nz": float("inf")}
    for label, q in plants:
        for kmh in speeds_kmh:
            loop, _ = nominal_loop(ctl, kmh / 3.6, q)
            for m in channel_margins(loop):
                where = f"{label}, {kmh:g} km/h, {m.channel}"
                if m.disk_margin < dm[0]:
                    dm = (m.disk_margin, where)
                if m.sensitivity_peak > sp[0]:
                    sp = (m.sensitivity_peak, where)
                if m.channel in gm:
                    gm[m.channel] = min(gm[m.channel], m.gm_db, key=abs)
                    pm[m.channel] = min(pm[m.channel], m.pm_deg)
    return RobustMargins(dm[0], sp[0], gm["delta"], pm["delta"], gm["Nz"], pm["Nz"], dm[1], sp[1])


def margins_admissible(nominal: RobustMargins) -> list[str]:
    """Why a design's margins on its own model break the constraint (empty: they meet it): a disk margin
    of at least :data:`DISK_MARGIN_MIN` and a sensitivity peak of at most :data:`SENSITIVITY_PEAK_MAX`."""
    why = []
    if not nominal.disk_margin >= DISK_MARGIN_MIN:
        why.append(f"disk margin {nominal.disk_margin:.2f} < {DISK_MARGIN_MIN:g} ({nominal.where_disk})")
    if not nominal.sensitivity_peak <= SENSITIVITY_PEAK_MAX:
        why.append(f"sensitivity peak {nominal.sensitivity_peak:.2f} > {SENSITIVITY_PEAK_MAX:g} "
                   f"({nominal.where_sensitivity})")
    return why


MARGIN_OMEGA = np.logspace(-2, 3, 1500)
"""[rad/s] The frequency grid of the margins (:func:`channel_margins`' default)."""


def loop_margins(ctl: TwoDofDesign, true_params: VehicleParams, speed: float,
                 omega: np.ndarray = MARGIN_OMEGA) -> tuple[float, float]:
    """``(disk margin, sensitivity peak)`` of :func:`nominal_loop`'s loop, the least and the largest over
    its four loop-breaking points, from the 2 x 2 frequency responses in numpy (what
    :func:`channel_margins` finds through python-control's interconnection, 100 times faster: the
    tuning evaluates it at every iteration). With ``G = K P`` at the plant inputs and ``G = P K`` at its
    outputs (``P`` the bicycle, ``K = Kp + Ki / s`` the law's feedback), breaking channel 1 with
    channel 2 closed leaves ``L = G11 - G12 G21 / (1 + G22)``."""
    A, B = lateral_matrices(true_params, speed)
    _, Kp, Ki, _ = ctl.gains(speed)
    s = 1j * np.asarray(omega, float)
    P = np.linalg.solve(s[:, None, None] * np.eye(2) - A, np.broadcast_to(B.astype(complex), (len(s), 2, 2)))
    K = Kp[None] + Ki[None] / s[:, None, None]
    dm, peak = float("inf"), 0.0
    for G in (K @ P, P @ K):
        for i, j in ((0, 1), (1, 0)):
            L = G[:, i, i] - G[:, i, j] * G[:, j, i] / (1.0 + G[:, j, j])
            dm = min(dm, disk_margin(L))
            peak = max(peak, float(np.max(np.abs(1.0 / (1.0 + L)))))
    return dm, peak
