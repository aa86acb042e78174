"""Lane kernels (``toolkit.kernels.lanes``): the vector math against glibc, the generated rollout against
casadi's own evaluation of the same function, and the batched loop against the loop case by case."""

import ctypes
import subprocess

import casadi as ca
import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction, default_wind
from evstab.plants.maneuvers import step_steer
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.loop import closed_loop as cl, loop_program
from evstab.toolkit.kernels import lanes
from evstab.toolkit.design import sweep as sw
from evstab.toolkit.kernels.compiled import compiler
from evstab.toolkit.loop.loop_program import LoopProgram

pytestmark = pytest.mark.skipif(compiler() is None, reason="no C compiler")


@pytest.fixture(scope="module")
def mathlib(tmp_path_factory):
    d = tmp_path_factory.mktemp("lanes")
    (d / "m.c").write_text(lanes.math_source())
    subprocess.run([compiler(), *lanes.CFLAGS, "-shared", "-fPIC", "-o", str(d / "m.so"), str(d / "m.c"), "-lm"],
                   check=True)
    return ctypes.CDLL(str(d / "m.so"))


def _call(lib, name, *xs):
    xs = [np.ascontiguousarray(x, dtype=float) for x in xs]
    y = np.empty_like(xs[0])
    getattr(lib, "ev_math_" + name)(ctypes.c_long(len(y)), *[a.ctypes.data_as(ctypes.c_void_p) for a in xs],
                                    y.ctypes.data_as(ctypes.c_void_p))
    return y


def _ulps(y, ref):
    return np.abs(y - ref) / np.spacing(np.maximum(np.abs(ref), np.finfo(float).tiny))


def _same(y, ref):
    """Equal including the sign of zero, or both NaN."""
    return ((y == ref) & (np.signbit(y) == np.signbit(ref))) | (np.isnan(y) & np.isnan(ref))


SPECIAL = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, -1e-310, 1e-300])
rng = np.random.default_rng(5)
CASES = {  # function, numpy reference, arguments: the ranges the loop uses and far beyond
    "sin": (np.sin, np.concatenate([rng.uniform(-10, 10, 200_000), rng.uniform(-1e6, 1e6, 20_000),
                                    [1.07e9, 2e9, 1e300]])),
    "cos": (np.cos, np.concatenate([rng.uniform(-10, 10, 200_000), rng.uniform(-1e6, 1e6, 20_000), [2e9]])),
    "atan": (np.arctan, np.concatenate([rng.uniform(-5, 5, 200_000),
                                        np.exp(rng.uniform(-700, 700, 20_000)) * rng.choice([-1, 1], 20_000)])),
    "exp": (np.exp, np.concatenate([rng.uniform(-50, 50, 200_000), rng.uniform(-745, 710, 20_000),
                                    [709.5, -708.5, 800.0, -800.0]])),
    "tanh": (np.tanh, np.concatenate([rng.uniform(-3, 3, 200_000), rng.uniform(-0.7, 0.7, 20_000),
                                      rng.uniform(-400, 400, 20_000), [0.625, -0.625, 19.06, 19.5]])),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_vector_math_is_within_two_ulp_of_glibc(mathlib, name):
    ref_fn, x = CASES[name]
    with np.errstate(all="ignore"):
        ref = ref_fn(x)
    y = _call(mathlib, name, x)
    finite = np.isfinite(ref) & (np.abs(ref) > 1e-300)
    # Cephes' documented peak errors are 1-2 ulp (Moshier 1989); glibc's are below 1
    assert _ulps(y[finite], ref[finite]).max() <= 2.0
    assert np.mean(y == ref) > 0.7  # most values round the same way
    with np.errstate(all="ignore"):
        sref = ref_fn(SPECIAL)
    assert np.all(_same(_call(mathlib, name, SPECIAL), sref)), name  # zeros keep their sign, inf/nan as C99


def test_vector_atan2_quadrants_axes_and_signed_zeros(mathlib):
    y = rng.normal(size=200_000) * rng.choice([1e-3, 1.0, 1e3], 200_000)
    x = rng.normal(size=200_000)
    ref = np.arctan2(y, x)
    assert _ulps(_call(mathlib, "atan2", y, x), ref).max() <= 2.0
    sp = np.array([0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, 1e-310, -2.5])
    Y, X = np.repeat(sp, len(sp)), np.tile(sp, len(sp))
    assert np.all(_same(_call(mathlib, "atan2", Y, X), np.arctan2(Y, X)))  # C99 Annex F, exactly


def _kernel(fn, tmp_path, stepped=(1,), width=lanes.WIDTH, flags=lanes.CFLAGS, schedule=True):
    src = lanes.rollout_source(fn, "k", lanes.Roles(stepped=stepped), width=width, schedule=schedule)
    tag = f"{width}{flags[0]}{schedule}"
    c = tmp_path / f"k{tag}.c"
    c.write_text(src)
    so = tmp_path / f"k{tag}.so"
    subprocess.run([compiler(), *flags, "-shared", "-fPIC", "-o", str(so), str(c), "-lm"], check=True)
    return lanes.LaneRollout(so, "k", fn, lanes.Roles(stepped=stepped))


def test_rollout_kernel_equals_casadi_on_exact_arithmetic(tmp_path):
    # x' = x + dt (a u - x / 4) with a per-case gain a, and outputs built from every exact operation
    # (division by a power of two is a product exactly): the kernel reproduces casadi's own
    # evaluation bit for bit, whatever the number of cases and the lane width
    x, u, a = ca.SX.sym("x", 2), ca.SX.sym("u"), ca.SX.sym("a")
    xn = ca.vertcat(x[0] + 0.01 * (a * u - x[0] / 4.0), ca.fmax(ca.fmin(x[1] + u * u, 3.0), -3.0))
    y = ca.vertcat(ca.sqrt(ca.fabs(x[0]) + 1.0), ca.if_else(x[0] < x[1], x[0] - x[1], 2 * x[1]),
                   ca.logic_and(x[0] > 0, x[1] <= 1), -x[0] / (1.0 + x[1] * x[1]))
    f = ca.Function("f", [x, u, a], [xn, y])
    n_cases, n = 11, 300
    r = np.random.default_rng(1)
    U = r.normal(size=(n_cases, n, 1))
    A = r.uniform(0.5, 2.0, size=(n_cases, 1))
    Z0 = r.normal(size=(n_cases, 2))
    for width in (1, lanes.WIDTH, lanes.WIDE):
        z_end, (Y,) = _kernel(f, tmp_path, width=width)(Z0, [U, A], n)
        for c in range(n_cases):
            Xs, Ys = f.mapaccum(n)(Z0[c], U[c].T, ca.repmat(A[c], 1, n))
            np.testing.assert_array_equal(Y[c], np.array(Ys).T)
            np.testing.assert_array_equal(z_end[c], np.array(Xs)[:, -1])


def test_rollout_kernel_is_the_same_at_every_lane_width(tmp_path):
    # the vector math (sin/cos sharing a reduction, atan, tanh, exp), reciprocal products and
    # branches of a nonlinear step: the kernel at 1, 2, 4 and 8 lanes gives the same bits, so the lane
    # width native_width() picks for a machine, the narrow kernel of one-case runs (NARROW) and the
    # optimisation level (kernel_flags) change only the speed
    x, u, a = ca.SX.sym("x", 3), ca.SX.sym("u"), ca.SX.sym("a")
    xn = ca.vertcat(x[0] + 0.01 * (ca.sin(x[1]) * a - ca.atan(x[0] / a)),
                    x[1] + 0.01 * (ca.cos(x[1]) + ca.tanh(u * x[2]) - x[1] / a),
                    ca.if_else(x[2] > 1.0, 0.5 * x[2], x[2] + 0.01 * ca.exp(-x[0] * x[0]) + u / 7.0))
    f = ca.Function("f", [x, u, a], [xn, ca.vertcat(ca.atan2(x[1], x[0]), ca.sqrt(x[2] * x[2] + u * u))])
    n_cases, n = 13, 400  # 13: partial blocks at every width
    r = np.random.default_rng(3)
    U, A, Z0 = r.normal(size=(n_cases, n, 1)), r.uniform(0.5, 2.0, size=(n_cases, 1)), r.normal(size=(n_cases, 3))
    runs = [_kernel(f, tmp_path, width=w, flags=lanes.kernel_flags(w))(Z0, [U, A], n)
            for w in (1, lanes.NARROW, lanes.WIDTH, lanes.WIDE)]
    runs.append(_kernel(f, tmp_path, width=lanes.WIDE)(Z0, [U, A], n))  # -O3 as well
    for z_end, (Y,) in runs[1:]:
        np.testing.assert_array_equal(z_end, runs[0][0])
        np.testing.assert_array_equal(Y, runs[0][1][0])


def test_rollout_kernel_reads_a_stepped_input_where_it_lies(tmp_path):
    # a stepped input of two signals given sample by sample (C order), signal by signal (the transposed
    # view of a (cases, signals, samples) array, as the sweep fills it), as every other case of a larger
    # array, and with a broadcast (zero-stride) signal: the same numbers read, so the same bits out
    x, u, a = ca.SX.sym("x", 2), ca.SX.sym("u", 2), ca.SX.sym("a")
    f = ca.Function("f", [x, u, a], [ca.vertcat(x[0] + 0.01 * (a * u[0] - x[1]), x[1] + 0.02 * u[1] * x[0]),
                                     ca.vertcat(u[0] - 2 * u[1], x[0] * u[1])])
    n_cases, n = 9, 200
    r = np.random.default_rng(5)
    U = r.normal(size=(n_cases, n, 2))
    A, Z0 = r.uniform(0.5, 2.0, size=(n_cases, 1)), r.normal(size=(n_cases, 2))
    k = _kernel(f, tmp_path)
    z_ref, (Y_ref,) = k(Z0, [U, A], n)
    signal_major = np.ascontiguousarray(U.transpose(0, 2, 1)).transpose(0, 2, 1)
    every_other = np.repeat(U, 2, axis=0)[::2]
    assert not signal_major.flags.c_contiguous and not every_other.flags.c_contiguous
    for V in (signal_major, every_other):
        z_end, (Y,) = k(Z0, [V, A], n)
        np.testing.assert_array_equal(Y, Y_ref)
        np.testing.assert_array_equal(z_end, z_ref)
    held = np.broadcast_to(U[:, :1, :], U.shape)  # the first sample's inputs, held (stride 0 along time)
    z_end, (Y,) = k(Z0, [held, A], n)
    _, (Y_held,) = k(Z0, [np.ascontiguousarray(held), A], n)
    np.testing.assert_array_equal(Y, Y_held)
    assert not np.array_equal(Y, Y_ref)


def test_native_width_is_a_lane_width_the_kernels_know():
    assert lanes.native_width() in (lanes.WIDTH, lanes.WIDE)
    assert loop_program.program(cl.loop_spec(load_vehicle("micro-ev"))).lanes.width == lanes.native_width()


def test_rollout_kernel_division_by_a_case_constant_is_a_product_within_one_ulp(tmp_path):
    x, u, m = ca.SX.sym("x"), ca.SX.sym("u"), ca.SX.sym("m")
    f = ca.Function("f", [x, u, m], [x + u / m, ca.vertcat(u / m, u / 3.0)])
    U = np.random.default_rng(2).normal(size=(5, 100, 1))
    M = np.array([[0.3], [7.0], [1e-3], [2.0], [123.456]])
    _, (Y,) = _kernel(f, tmp_path)(np.zeros((5, 1)), [U, M], 100)
    np.testing.assert_array_equal(Y[3, :, 0], U[3, :, 0] / 2.0)  # a power of two: exact
    ref = np.stack([U[:, :, 0] / M, U[:, :, 0] / 3.0], axis=-1)
    assert _ulps(Y, ref).max() <= 1.0


def test_rollout_kernel_refuses_what_it_cannot_lay_out():
    x = ca.SX.sym("x", 2, 2)
    f = ca.Function("f", [x], [x])
    with pytest.raises(lanes.CompileError, match="dense column vector"):
        lanes.rollout_source(f, "k", lanes.Roles(stepped=()))
    mx = ca.MX.sym("x")
    with pytest.raises(lanes.CompileError, match="SX function"):
        lanes.rollout_source(ca.Function("g", [mx], [2 * mx]), "k", lanes.Roles(stepped=()))


def test_lane_kernel_loop_equals_casadis_generated_c():
    """The loop's lane kernel against casadi's C of the same traced step: the only differences are
    the vector math (<= 2 ulp per call) and reciprocal products (<= 1 ulp), which a stable closed
    loop keeps at rounding level over 10 s."""
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=0.2, duration=10.0)
    dist = Disturbances(wind=default_wind(p))
    sens = SensorConfig()
    spec = cl.loop_spec(p, sensors=sens)
    fast, ref = loop_program.program(spec), loop_program.LoopProgram(cl.traced(spec), lanes=False)
    assert fast.backend == "lanes" and ref.backend == "c"
    U, z0, pv = fast.inputs(p, man, dist, sens, 0)
    th = fast.theta()
    Y, E, M = fast.run(U, z0, pv, th, meas=True)
    Yr, Er, Mr = ref.run(U, z0, pv, th, meas=True)
    # measured: 3e-14 in the truth, 8e-12 N m in the yaw moment (of ~300 N m)
    for a, b in ((Y, Yr), (E, Er), (M, Mr)):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-11)


def test_the_order_the_kernel_writes_a_step_in_changes_no_bit(tmp_path):
    """The loop step written in casadi's instruction order and in :func:`toolkit.kernels.lanes._schedule`'s
    (the kernels' order, for speed): the same operations on the same values, so the same bits over a
    3 s closed-loop run, on every output and the final state."""
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=0.2, duration=3.0)
    sens = SensorConfig()
    spec = cl.loop_spec(p, sensors=sens)
    prog = loop_program.program(spec)
    step = cl._lane_step(cl.traced(spec))
    written = [lanes.rollout_source(step, "k", cl.LANE_ROLES, lanes.NARROW, schedule=s).split("for (long k = 0;")[1]
               for s in (True, False)]
    assert written[0] != written[1] and sorted(written[0].splitlines()) == sorted(written[1].splitlines())
    U, z0, pv = prog.inputs(p, man, Disturbances(wind=default_wind(p)), sens, 0)
    th = prog.theta()
    casadi_order = _kernel(step, tmp_path, stepped=cl.LANE_ROLES.stepped, width=lanes.NARROW,
                           flags=lanes.kernel_flags(lanes.NARROW), schedule=False)
    z, (Y, E, M) = casadi_order(z0[None], [U[None], pv[None], th[None]], len(U))
    Ys, Es, Ms, zs = prog.run(U, z0, pv, th, meas=True, final_state=True)
    for a, b in ((Y[0], Ys), (E[0], Es), (M[0], Ms), (z[0], zs)):
        np.testing.assert_array_equal(a, b)


def test_batched_and_per_case_rollouts_agree_on_every_output_of_a_50_case_sweep():
    """Lanes do not see each other: each case of a 50-case batch (blocks of lanes, the last
    partial at 4 or 8 lanes) equals the same case run alone, on every output, to 1e-12 (they are the same
    operations, so in fact bit for bit). A case run alone, and two run together, go through the narrow
    kernel (:data:`toolkit.kernels.lanes.NARROW` lanes) where the machine's vectors are wider: a kernel of another
    width, compiled separately, which computes the same."""
    cfg = sw.SweepConfig(load_vehicle("compact-ev"))
    cases = sw.sweep_cases(quick=False)[:50]
    prog = loop_program.program(cfg.spec())
    assert prog.backend == "lanes"
    runs = [sw.case_inputs(cfg, c, prog)[1][0] for c in cases]  # the lane change of each case
    theta = np.array([prog.theta(gyro_bias=c.gyro_bias, gyro_scale_error=c.gyro_scale_error, mu_assumed=0.9)
                      for c in cases])
    U = np.stack([r[0] for r in runs])
    Y, E, M, z = prog.run_batch(U, np.stack([r[1] for r in runs]), np.stack([r[2] for r in runs]), theta,
                                meas=True, final_state=True)
    assert len({c.mu for c in cases}) > 3 and len({c.speed_kmh for c in cases}) > 2  # different cases
    for i, (Ui, z0, pv) in enumerate(runs):
        y, e, m, zi = prog.run(Ui, z0, pv, theta[i], meas=True, final_state=True)
        for a, b in ((Y[i], y), (E[i], e), (M[i], m), (z[i], zi)):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
            np.testing.assert_array_equal(a, b)
    pair = prog.run_batch(U[[7, 42]], np.stack([runs[7][1], runs[42][1]]), np.stack([runs[7][2], runs[42][2]]),
                          theta[[7, 42]], meas=True, final_state=True)
    for a, b in zip(pair, (Y, E, M, z)):
        np.testing.assert_array_equal(a, b[[7, 42]])
    if lanes.native_width() > lanes.NARROW:  # the single runs and the pair were the narrow kernel's
        assert prog._kernel_for(1).width == prog._kernel_for(2).width == lanes.NARROW
        assert prog._kernel_for(3) is prog.lanes and prog.lanes.width == lanes.native_width()


def test_run_batch_into_given_arrays_returns_them_with_the_same_numbers():
    """``out=`` (the sweep's reused memory) changes where Y and E land, not what they hold; arrays
    holding garbage from an earlier block are overwritten everywhere (NaN-filled here)."""
    cfg = sw.SweepConfig(load_vehicle("compact-ev"))
    prog = loop_program.program(cfg.spec())
    cases = sw.sweep_cases(quick=True)[:prog.lanes.width + 1]  # one full block of lanes and a partial one
    runs = [sw.case_inputs(cfg, c, prog)[1][1] for c in cases]  # the step steer of each case
    theta = np.array([prog.theta(gyro_bias=c.gyro_bias, gyro_scale_error=c.gyro_scale_error) for c in cases])
    args = (np.stack([r[0] for r in runs]), np.stack([r[1] for r in runs]), np.stack([r[2] for r in runs]), theta)
    other = LoopProgram(prog.spec, lanes=False)  # casadi's generated C, case by case
    assert (prog.backend, other.backend) == ("lanes", "c")
    for program, a in ((prog, args), (other, [x[:1] for x in args])):  # one case on the slow backend
        Y, E = program.run_batch(*a)
        out = (np.full(Y.shape, np.nan), np.full(E.shape, np.nan))
        Y2, E2 = program.run_batch(*a, out=out)
        assert Y2 is out[0] and E2 is out[1]
        np.testing.assert_array_equal(Y2, Y)
        np.testing.assert_array_equal(E2, E)
        with pytest.raises(cl.LoopError, match=r"out\[1\] \(extra\) must be a C-ordered float"):
            program.run_batch(*a, out=(out[0], out[1][:, :-1]))  # one sample short: refused, nothing written


def test_sweep_rows_do_not_depend_on_the_batching():
    cfg = sw.SweepConfig(load_vehicle("compact-ev"))
    cases = [sw.Case(i, mu=mu, speed_kmh=v, group="t") for i, (mu, v) in enumerate([(1.0, 60.0), (0.4, 80.0),
                                                                                    (0.7, 100.0)])]
    together = sw.evaluate_cases(cfg, cases, [sw.PAPER, sw.PAPER], linear=False)
    alone = [r for c in cases for r in sw.evaluate_case(cfg, c, [sw.PAPER, sw.PAPER], linear=False)]
    def nan_free(rows):  # spectral_radius is NaN without the linear verdicts
        return [{k: ("nan" if isinstance(v, float) and np.isnan(v) else v) for k, v in r.items()} for r in rows]

    assert nan_free(together) == nan_free(alone)


def test_schedule_in_a_lane_kernel_is_the_firmwares_table_lookup(tmp_path):
    """A schedule read traced for a lane kernel is a call node; the kernel runs the segment lookup in its place,
    the numpy branch's (and the exported C's) arithmetic bit for bit, where casadi evaluates the
    hat-function sums, equal to rounding."""
    from evstab.controllers.schedule import ROWS, SpeedSchedule
    from evstab.plants.backend import call_nodes
    s = SpeedSchedule.build(load_vehicle("compact-ev"))
    z, v = ca.SX.sym("z"), ca.SX.sym("v")
    inline = ca.vertcat(*s.values(v, cl.CASADI))
    assert not ca.Function("h", [v], [inline]).has_free() and ca.depends_on(inline, v)
    with call_nodes():
        rows = ca.vertcat(*s.values(v, cl.CASADI))
    f = ca.Function("f", [z, v], [z, rows])
    assert any(f.instruction_id(k) == ca.OP_CALL for k in range(f.n_instructions()))
    speeds = np.concatenate([np.geomspace(0.5, 90.0, 3001), s.speeds, [0.0, -3.0, np.inf]])
    n = len(speeds)
    k = _kernel(f, tmp_path)
    _, (R,) = k(np.zeros((1, 1)), [speeds.reshape(1, n, 1)], n)
    ref = np.stack(s.values(np.maximum(speeds, 0.0)), axis=-1)  # numpy clamps v at 1e-300 first
    ok = speeds >= 0.0
    np.testing.assert_array_equal(R[0][ok], ref[ok])
    np.testing.assert_array_equal(R[0][speeds < 0], np.tile(np.asarray(s.table)[:, 0], (1, 1)))  # 1/v < 0: first point
    hat = np.array(ca.Function("g", [v], [inline]).map(int(ok.sum()))(speeds[ok][None, :])).T
    np.testing.assert_allclose(R[0][ok], hat, rtol=1e-13, atol=1e-13 * np.abs(np.asarray(s.table)).max())
    assert R.shape[2] == len(ROWS)


def test_tyre_shape_in_a_lane_kernel_is_the_table(tmp_path):
    """The tyre's shape function traced for a lane kernel is a call node; the kernel reads the table in its
    place, the numpy branch's arithmetic bit for bit, where casadi evaluates the formula; a lane with
    another shape or curvature evaluates the formula (the Cephes functions: within a few units in the
    last place of casadi's, as test_vector_math_agrees_with_libm measures), whatever its neighbours."""
    from evstab.plants.backend import CASADI, NUMPY, call_nodes
    from evstab.plants.tires import TABLE_CURVATURE, TABLE_SHAPE, _casadi_function, combined_forces, shape_table

    def _tyre_call(u, c, e):
        return _casadi_function(shape_table())(ca.vertcat(u, c, e))
    z, k, ta, c, e = (ca.SX.sym(n) for n in ("z", "k", "ta", "c", "e"))
    args = (4000.0, 3500.0, 0.9, 52000.0, 80000.0)  # F_z, F_z0, mu, C_alpha, C_kappa of a car's tyre
    inline = ca.vertcat(*combined_forces(k, ta, *args[:3], args[3], args[4], c, e, CASADI))
    with call_nodes():
        traced = ca.vertcat(*combined_forces(k, ta, *args[:3], args[3], args[4], c, e, CASADI))
    u = ca.SX.sym("u")
    with call_nodes():
        ratio = _tyre_call(u, c, e)
    f = ca.Function("f", [z, ca.vertcat(k, ta, c, e, u)], [z, ca.vertcat(traced, ratio)])
    assert any(f.instruction_id(i) == ca.OP_CALL for i in range(f.n_instructions()))
    assert not any(ca.Function("g", [k, ta, c, e], [inline]).instruction_id(i) == ca.OP_CALL
                   for i in range(ca.Function("g", [k, ta, c, e], [inline]).n_instructions()))
    rng = np.random.default_rng(5)
    n = 4003
    kappa = np.concatenate([rng.normal(0.0, 0.05, n - 3), [0.0, 1.0, -3.0]])
    tan_a = np.concatenate([rng.normal(0.0, 0.1, n - 3), [0.0, 40.0, 0.0]])
    shape = np.full(n, TABLE_SHAPE)
    curv = np.full(n, TABLE_CURVATURE)
    other = np.arange(n) % 5 == 3  # every fifth lane another tyre: lanes of either kind in most vectors
    shape[other], curv[other] = 1.6, 0.5
    slip = np.concatenate([np.geomspace(1e-9, 1e9, n - 4), [0.0, 2.0, np.inf, np.nan]])
    U = np.stack([kappa, tan_a, shape, curv, slip], axis=-1)[None]
    kern = _kernel(f, tmp_path, width=lanes.native_width(), flags=lanes.kernel_flags(lanes.native_width()))
    _, (R,) = kern(np.zeros((1, 1)), [U], n)
    mine = ~other
    np.testing.assert_array_equal(R[0][mine, 2], shape_table().ratio(slip[mine]))  # NaN = NaN
    fx, fy = combined_forces(kappa[mine], tan_a[mine], *args, TABLE_SHAPE, TABLE_CURVATURE, NUMPY)
    scale = args[2] * args[0]  # the force's magnitude, mu F_z
    # the kernel divides by a per-case constant as a product with its reciprocal (lanes._strength_reduce):
    # a unit in the last place of the force, 5e-13 N
    np.testing.assert_allclose(R[0][mine, :2], np.stack([fx, fy], axis=-1), rtol=0, atol=4e-16 * scale)
    g = ca.Function("g", [ca.vertcat(k, ta, c, e)], [inline]).map(n)
    formula = np.array(g(U[0, :, :4].T)).T
    # the table is the formula to 3e-15 of the force (ShapeTable.max_error: F_rel), plus a unit in the last
    # place of the products around it
    np.testing.assert_allclose(R[0][mine, :2], formula[mine], rtol=5e-15, atol=1e-15 * scale)
    np.testing.assert_allclose(R[0][other, :2], formula[other], rtol=0, atol=1e-15 * scale)
    assert shape_table().name in lanes.rollout_source(f, "k", lanes.Roles(stepped=(1,)))


def test_simulate_many_equals_simulate_run_by_run():
    """An FMVSS 126 series' runs stepped together equal each run simulated alone."""
    from evstab.plants.maneuvers import sine_with_dwell
    from evstab.toolkit.loop.simulator import simulate, simulate_many
    p = load_vehicle("compact-ev")
    mans = [sine_with_dwell(80 / 3.6, s * np.radians(a) / p.steering_ratio) for a in (60.0, 180.0) for s in (1, -1)]
    dist = Disturbances(friction=Friction(mu=0.6))
    many = simulate_many(p, "two-track", mans, disturbances=dist, seed=2, controller="two-dof")
    for man, r in zip(mans, many):
        one = simulate(p, "two-track", man, disturbances=dist, seed=2, controller="two-dof")
        for group in ("truth", "commands", "measurements"):
            for k, v in getattr(one, group).items():
                np.testing.assert_array_equal(getattr(r, group)[k], v, err_msg=f"{group} {k}")


def test_the_benchmarks_plant_kernel_retraces_the_loops_truth():
    """``benchmarks/_plant.py`` times the loop's plant alone (its RK4 and output equation as a lane kernel
    of their own, fed what the loop applied): it measures the loop's plant only if it computes the
    loop's truth. The same functions on the same kernel machinery, so the same operations: measured
    bit for bit on this run and 9e-14 (in positions of ~100 m, the last bits) on the sweep's cases;
    1e-9 leaves room for a compiler that orders a hoisted product differently."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import _plant
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=0.2, duration=2.0)
    sens = SensorConfig()
    spec = cl.loop_spec(p, sensors=sens)
    prog = loop_program.program(spec)
    U, z0, pv = prog.inputs(p, man, Disturbances(wind=default_wind(p)), sens, 0)
    Y, E = prog.run(U, z0, pv, prog.theta())
    kernel = _plant.plant_kernel(spec)
    *_, diff = _plant.retrace(spec, kernel, U[None], z0[None], pv[None], E[None], Y[None])
    assert diff <= 1e-9
    # and it is not trivially so: a steer one period late gives another truth
    E2 = E.copy()
    E2[1:, cl.EXTRA.index("steer")] = E[:-1, cl.EXTRA.index("steer")]
    *_, late = _plant.retrace(spec, kernel, U[None], z0[None], pv[None], E2[None], Y[None])
    assert late > 1e-6
