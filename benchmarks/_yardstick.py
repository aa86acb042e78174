"""The benchmarks' yardstick: a hand-written dense 5-state Kalman step in plain C (gcc -O2).

Predict ``x = F x``, ``P = F P F' + Q`` and one scalar update (``S = H P H' + R``, gain,
``P = P - K H P``) on dense 5 x 5 matrices: about the arithmetic of the filter core a stability ECU runs
every millisecond. It is compiled and timed in the calling process (the timing loop is in C,
``clock_gettime`` around ``n`` steps, the best of runs spread over a second), so that every
benchmark can print its own per-step figure as a multiple of it, on the same machine in the same
run. None without a C compiler.
"""

from __future__ import annotations

import ctypes
import functools
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

#: The yardstick's step alone (``yardstick_step``), for harnesses that time it beside their own code.
STEP_SRC = r"""
#define N 5

static void yardstick_step(double x[N], double P[N * N], const double F[N * N], const double Q[N * N],
                 const double H[N], double R, double z)
{
    double xn[N], FP[N * N], Pn[N * N], PH[N], K[N];
    int i, j, k;
    for (i = 0; i < N; ++i) {
        xn[i] = 0.0;
        for (j = 0; j < N; ++j) xn[i] += F[i * N + j] * x[j];
    }
    for (i = 0; i < N; ++i)
        for (j = 0; j < N; ++j) {
            FP[i * N + j] = 0.0;
            for (k = 0; k < N; ++k) FP[i * N + j] += F[i * N + k] * P[k * N + j];
        }
    for (i = 0; i < N; ++i)
        for (j = 0; j < N; ++j) {
            double s = Q[i * N + j];
            for (k = 0; k < N; ++k) s += FP[i * N + k] * F[j * N + k];
            Pn[i * N + j] = s;
        }
    double S = R, innov = z;
    for (i = 0; i < N; ++i) {
        PH[i] = 0.0;
        for (j = 0; j < N; ++j) PH[i] += Pn[i * N + j] * H[j];
        S += H[i] * PH[i];
        innov -= H[i] * xn[i];
    }
    for (i = 0; i < N; ++i) {
        K[i] = PH[i] / S;
        x[i] = xn[i] + K[i] * innov;
    }
    /* P = Pn - K (H Pn) (the symmetric Pn: H Pn = PH') */
    for (i = 0; i < N; ++i)
        for (j = 0; j < N; ++j) P[i * N + j] = Pn[i * N + j] - K[i] * PH[j];
}
"""

#: The yardstick's matrices (a 5-state chain, a two-state measurement) and the update's measurement:
#: ``YARDSTICK_SETUP`` declares and fills x, P, F, Q, H; ``yardstick_step`` is then called as
#: ``YARDSTICK_CALL`` inside a loop over ``k``.
YARDSTICK_SETUP = r"""
        double x[N] = {0}, P[N * N] = {0}, F[N * N] = {0}, Q[N * N] = {0}, H[N] = {1, 0, 1, 0, 0};
        for (int i = 0; i < N; ++i) {
            P[i * N + i] = 1.0;
            Q[i * N + i] = 1e-6;
            F[i * N + i] = 1.0;
            if (i + 1 < N) F[i * N + i + 1] = 1e-3;
        }
"""
YARDSTICK_CALL = "yardstick_step(x, P, F, Q, H, 1e-4, 1e-3 * (double)(k % 97))"

_SRC = "#define _POSIX_C_SOURCE 199309L\n#include <time.h>\n" + STEP_SRC + r"""
double yardstick_ns(long n, int repeats, double *sink)
{
    double best = 1e300;
    for (int r = 0; r < repeats; ++r) {""" + YARDSTICK_SETUP + r"""
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (long k = 0; k < n; ++k) """ + YARDSTICK_CALL + r""";
        clock_gettime(CLOCK_MONOTONIC, &t1);
        double ns = ((double)(t1.tv_sec - t0.tv_sec) * 1e9 + (double)(t1.tv_nsec - t0.tv_nsec)) / (double)n;
        if (ns < best) best = ns;
        *sink += x[0] + P[0];
    }
    return best;
}
"""


@functools.lru_cache(maxsize=None)
def yardstick_pass():
    """A callable ``f(n)``: one timed run of ``n`` yardstick steps, ns per step (the library compiled once
    per process); None without a C compiler. Benchmarks that time the yardstick beside their own code,
    in alternating passes, use it."""
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        return None
    tmp = tempfile.mkdtemp(prefix="evstab_yardstick_")
    src, lib = Path(tmp) / "yardstick.c", Path(tmp) / "yardstick.so"
    src.write_text(_SRC)
    subprocess.run([cc, "-std=c99", "-O2", "-shared", "-fPIC", "-o", str(lib), str(src)], check=True,
                   capture_output=True)
    dll = ctypes.CDLL(str(lib))
    shutil.rmtree(tmp, ignore_errors=True)  # the loaded library stays mapped
    dll.yardstick_ns.restype = ctypes.c_double
    dll.yardstick_ns.argtypes = [ctypes.c_long, ctypes.c_int, ctypes.POINTER(ctypes.c_double)]
    sink = ctypes.c_double(0.0)
    return lambda n: float(dll.yardstick_ns(n, 1, ctypes.byref(sink)))


@functools.lru_cache(maxsize=None)
def yardstick_ns(n: int = 200_000, repeats: int = 25, pause: float = 0.02) -> float | None:
    """ns per step of the hand-written C Kalman step, measured once per process (the printed line and
    the written table carry the same figure): the best of ``repeats`` runs of ``n`` steps with
    ``pause`` seconds between them. On this shared 2-core machine single runs range over 2x
    (106-216 ns in 30 runs, the slow ones in spells of a quarter of a second or more), so the runs
    are spread over about a second; the best is the machine's undisturbed speed."""
    one = yardstick_pass()
    if one is None:
        return None
    best = float("inf")
    for _ in range(repeats):
        best = min(best, one(n))
        time.sleep(pause)
    return best


def yardstick_line(per_step_ns: float, what: str, y: float | None = None) -> str:
    """The line every benchmark prints: its per-step figure against the yardstick (``y`` ns per step
    when the caller timed it beside its own code, else :func:`yardstick_ns`)."""
    y = yardstick_ns() if y is None else y
    if y is None:
        return "yardstick: no C compiler, no comparison"
    return (f"yardstick: hand-written dense 5-state Kalman step in C (gcc -O2) {y:.0f} ns per step in this run; "
            f"{what} {per_step_ns:.0f} ns = {per_step_ns / y:.1f}x it")
