"""Compiled time loops: casadi step functions, ``mapaccum`` and C code generation.

The plant's ``f(x, u, w, p)`` is traced once with casadi symbols (parameters
are symbolic inputs, so one compiled library serves every parameter set of a
model), integrated with classic RK4 (``n_sub`` sub-steps per sample, inputs held),
and rolled out over a chunk of samples by ``mapaccum``. The chunk is compiled to
C with casadi's code generator and ``gcc -O3`` into a shared library cached under
``$EVSTAB_CACHE`` (default ``~/.cache/evstab``); with no C compiler the same casadi
function runs in casadi's virtual machine (slower, identical numbers to ~1e-15).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import fields
from functools import lru_cache
from pathlib import Path
from types import SimpleNamespace

import ctypes

import casadi as ca
import numpy as np

from evstab.plants import COMMANDS, DISTURBANCES, TRUTH, PlantModel, VehicleParams
from evstab.plants.errors import CompileError

CODE_VERSION = "3"
"""Bump when generated code changes meaning (invalidates the compiled cache)."""
CHUNK = 2000
"""Samples per compiled rollout call."""
CASADI_VERSION = str(getattr(ca, "__version__"))
"""The casadi that traced and printed a library: part of every compiled-cache key."""


# ----------------------------------------------------------------- parameters
def numeric_fields(p: VehicleParams) -> tuple[str, ...]:
    """Names of the numeric, set fields of ``p`` (the symbolic parameter vector's order)."""
    return tuple(f.name for f in fields(p) if f.name not in ("name", "source") and getattr(p, f.name) is not None)


def param_vector(p: VehicleParams, names: tuple[str, ...]) -> np.ndarray:
    return np.array([float(getattr(p, n)) for n in names])


def symbolic_params(p: VehicleParams, names: tuple[str, ...]):
    """A stand-in for ``p`` whose set fields are casadi symbols (unset ones stay None)."""
    vec = ca.SX.sym("p", len(names))
    return symbolic_view(p, names, vec), vec


def symbolic_view(p: VehicleParams, names: tuple[str, ...], vec):
    """A stand-in for ``p`` whose set fields ``names`` are the entries of the casadi vector ``vec``."""
    ns = {f.name: None for f in fields(p)}
    ns.update({n: vec[i] for i, n in enumerate(names)})
    ns["name"], ns["source"] = p.name, p.source
    sp = SimpleNamespace(**ns)
    sp.wheelbase = sp.lf + sp.lr
    return sp


# ------------------------------------------------------------------ functions
def rk4_substeps(model: PlantModel, p: VehicleParams, dt: float) -> int:
    """Number of RK4 sub-steps per sample that keeps the stiffest mode stable."""
    if model.max_step is None:
        return 1
    return max(1, int(np.ceil(dt / model.max_step(p))))


def rk4_step(model: PlantModel, p, x, cmd, w, dt: float, n_sub: int):
    """One sample of classic RK4 (``n_sub`` sub-steps, commands held), numpy or casadi symbols."""
    h = dt / n_sub

    def rhs(xx):
        return model.f(xx, model.command_map(cmd, xx, p), w, p)

    for _ in range(n_sub):
        k1 = rhs(x)
        k2 = rhs(x + h / 2 * k1)
        k3 = rhs(x + h / 2 * k2)
        k4 = rhs(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def build_step(model: PlantModel, p: VehicleParams, dt: float, n_sub: int):
    """casadi ``step(x, cmd, w, pvec) -> (x_next, y)``: RK4 over one sample, commands held.

    ``y`` are the truth outputs at the start of the sample; the command map (e.g.
    the speed hold) is evaluated at every RK4 stage.
    """
    names = numeric_fields(p)
    sp, pvec = symbolic_params(p, names)
    x = ca.SX.sym("x", len(model.states))
    cmd = ca.SX.sym("cmd", len(COMMANDS))
    w = ca.SX.sym("w", len(DISTURBANCES))
    xk = rk4_step(model, sp, x, cmd, w, dt, n_sub)
    y = model.h(x, model.command_map(cmd, x, sp), w, sp)
    step = ca.Function("step", [x, cmd, w, pvec], [xk, y], ["x", "cmd", "w", "p"], ["x_next", "y"])
    return step, names


@lru_cache(maxsize=1)
def source_digest() -> str:
    """Digest of evstab's own source, every module and C file of ``plants``, ``controllers`` and
    ``toolkit``: part of every compiled-cache key, so a code change can never reuse a stale
    library. (Per-module lists went stale: a traced graph reaches into modules its key did
    not name, and a changed filter once reused an old tuning library.)"""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[2]  # toolkit/kernels/compiled.py: the folder of plants, controllers, toolkit
    for pkg in ("plants", "controllers", "toolkit"):
        for f in sorted(g for ext in ("*.py", "*.c", "*.h") for g in (root / pkg).rglob(ext)):
            h.update(f.relative_to(root).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def cache_key(prefix: str, *parts) -> str:
    """Compiled-cache key: ``prefix`` plus a digest of ``parts`` (their repr), the casadi version
    and :func:`source_digest`."""
    return prefix + "_" + hashlib.sha256(repr((parts, CASADI_VERSION, source_digest())).encode()).hexdigest()[:20]


def with_fields(obj, **values):
    """A copy of a frozen dataclass with fields replaced without validation: for casadi symbols
    (run-time inputs of a traced function), which validation cannot check."""
    import copy
    c = copy.copy(obj)
    for k, v in values.items():
        object.__setattr__(c, k, v)
    return c


def _cache_dir() -> Path:
    root = os.environ.get("EVSTAB_CACHE") or os.path.join(os.path.expanduser("~"), ".cache", "evstab")
    return Path(root)


def cache_files() -> list[Path]:
    """The files evstab wrote into the compiled cache (generated C and shared libraries)."""
    d = _cache_dir()
    return sorted(p for p in d.glob("evstab_*") if p.is_file()) if d.is_dir() else []


def clear_cache() -> tuple[int, int]:
    """Delete the compiled cache's files; returns (files, bytes) removed. Libraries a running
    process has loaded stay mapped in it; the next run compiles again."""
    n = size = 0
    for p in cache_files():
        try:
            s = p.stat().st_size
            p.unlink()
        except FileNotFoundError:  # another process removed it first
            continue
        n, size = n + 1, size + s
    return n, size


def compiler() -> str | None:
    """The C compiler used for generated code (``$CC`` or gcc/cc on PATH), or None."""
    for cand in (os.environ.get("CC"), "gcc", "cc"):
        if cand and shutil.which(cand):
            return cand
    return None


def cached_library(key: str) -> Path | None:
    """The compiled library for ``key`` if it is already in the cache (and a compiler exists)."""
    lib = _cache_dir() / f"evstab_{key}.so"
    return lib if (compiler() is not None and lib.is_file()) else None


def shared(fn: ca.Function) -> ca.Function:
    """An SX function with its repeated subexpressions computed once (casadi's ``cse``: an operation
    on the same operands as an earlier one reuses its value); other functions as they are.

    A trace repeats much: every RK4 stage takes the sine and cosine of the same held steer angle,
    and a loop step reads the same schedule row for its filter and its law. The values are exactly
    the same, as the merged operations were the same (the tests compare compiled code with numpy
    bit for bit where they did before). The micro-ev's two-track loop step goes from 4,279 to 3,698
    instructions (55 to 34 sines); compact-ev's loop Jacobian of the stability analysis from
    102,926 to 93,417."""
    if not fn.is_a("SXFunction"):
        return fn
    outs = ca.cse(fn.call(fn.sx_in()))
    return ca.Function(fn.name(), fn.sx_in(), outs, fn.name_in(), fn.name_out())


def compile_library(funcs: list, key: str, opt: str = "-O3") -> Path | None:
    """Generate C for casadi ``funcs`` (SX functions after :func:`shared`), compile (``opt``) to a
    cached shared library; None without a compiler."""
    def write(c_file: Path) -> None:
        cg = ca.CodeGenerator(c_file.name, {"with_header": False})
        for fn in funcs:
            cg.add(shared(fn))
        cg.generate(str(c_file.parent) + os.sep)
    return compile_source(write, key, (opt,), "casadi's virtual machine")


def compile_source(write, key: str, flags: tuple[str, ...], fallback: str) -> Path | None:
    """The cached shared library ``evstab_<key>.so``, built when missing: ``write(path)`` writes its C
    source to ``path`` (in a temporary folder), compiled with ``flags`` and moved into place
    atomically; None without a compiler, or (with a warning naming ``fallback``, what runs instead)
    when the compiler fails."""
    cc = compiler()
    if cc is None:
        return None
    out_dir = _cache_dir()
    lib = out_dir / f"evstab_{key}.so"
    if lib.is_file():
        return lib
    out_dir.mkdir(parents=True, exist_ok=True)
    with _build_lock(out_dir / f"evstab_{key}.lock"):
        if lib.is_file():  # another process built it while this one waited
            return lib
        return _build(write, cc, lib, key, flags, fallback)


@contextlib.contextmanager
def _build_lock(path: Path):
    """One build of a library at a time, across processes: an advisory lock on ``path``. The
    process-pool workers of a sweep start together and need the same libraries; without the lock
    each compiled them (the loop Jacobian, 10 s, twice in a cold test run). Where there is no
    ``fcntl`` (Windows), builds may overlap: each writes the whole library and renames it into place.

    The lock file is removed by its holder when done: a process that waited on it finds the library
    built; one that comes later finds the library before it looks for a lock."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            path.unlink(missing_ok=True)
            fcntl.flock(fh, fcntl.LOCK_UN)


KERNELS = {"est": "the estimator", "loop": "the closed loop", "loop_lanes": "the closed loop's lane kernel",
           "loopjac": "the closed loop's Jacobian", "tune": "the tuning's rollout", "tune_lanes": "the tuning's lane "
           "kernel", "ecu": "the ECU step", "bench_plant": "the benchmark's plant kernel"}
"""What each cache-key prefix compiles, for the progress line (:func:`compile_notice`)."""


def compile_notice(key: str) -> str | None:
    """The line said before a compile (``None``: not shown): on a terminal, or with ``EVSTAB_PROGRESS=1``
    (``0`` silences it), what is compiled and that it happens once per code and model."""
    flag = os.environ.get("EVSTAB_PROGRESS")
    if flag == "0" or (flag != "1" and not sys.stderr.isatty()):
        return None
    prefix = key.rsplit("_", 1)[0] if "_" in key else ""
    what = KERNELS.get(prefix, "a plant model" if not prefix else prefix)
    return f"evstab: compiling {what} to C (first run with this code and model only; cached in {_cache_dir()})"


def _build(write, cc: str, lib: Path, key: str, flags: tuple[str, ...], fallback: str) -> Path | None:
    notice = compile_notice(key)
    if notice:
        print(notice + " ...", file=sys.stderr, end="", flush=True)
    t0 = time.perf_counter()
    try:
        return _compile(write, cc, lib, key, flags, fallback)
    finally:
        if notice:
            print(f" {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)


def _compile(write, cc: str, lib: Path, key: str, flags: tuple[str, ...], fallback: str) -> Path | None:
    with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
        c_file = Path(tmp) / f"evstab_{key}.c"
        write(c_file)
        tmp_lib = c_file.with_suffix(".so")
        res = subprocess.run([cc, *flags, "-shared", "-fPIC", "-o", str(tmp_lib), str(c_file), "-lm"],
                             capture_output=True, text=True)
        if res.returncode != 0:
            warnings.warn(f"evstab: C compilation failed, using {fallback}: {res.stderr[:500]}")
            return None
        os.replace(tmp_lib, lib)  # atomic: a concurrent reader sees the old or the complete file
    return lib


def load_chunk_library(key: str, build, name: str, required: bool = False) -> "CFunction | None":
    """The compiled chunk function ``name`` for cache ``key``: loaded from the cache without
    calling ``build`` (which returns the casadi function) when it is there, compiled otherwise;
    None without a C compiler (``required``: raise instead)."""
    lib = cached_library(key)
    if lib is None and compiler() is not None:
        lib = compile_library([build()], key)
    if lib is None:
        if required:
            raise CompileError("no C compiler available for backend 'c'")
        return None
    return CFunction(ctypes.CDLL(str(lib)), name)


def run_chunks(z0, inputs: list, n_out: int, chunk: int, *, c_fn=None, casadi_fn=None, constants=(),
               fix_column: int | None = None, final_state: bool = False):
    """Roll a chunk function ``(z0, U_1 .. U_m, c_1 ..) -> (z_end, Y)`` over all samples.

    ``inputs`` are (N, k_i) arrays (one row per sample), ``constants`` arrays passed
    unchanged to every chunk. The last chunk is padded with the last row (``fix_column``
    of the first input set to 0 there: padded samples carry no GPS fix). Runs the compiled
    ``c_fn`` on numpy buffers when given, else ``casadi_fn``. Returns Y (N, n_out), and with
    ``final_state`` also the state after the last chunk (after the padding samples, if any:
    callers that need the state after exactly N samples pass a multiple of ``chunk``).
    """
    n = inputs[0].shape[0]
    n_pad = -(-n // chunk) * chunk
    padded = []
    for U in inputs:
        P = np.empty((n_pad, U.shape[1]))
        P[:n] = U
        P[n:] = U[-1]
        padded.append(P)
    if fix_column is not None:
        padded[0][n:, fix_column] = 0.0
    consts = [np.ascontiguousarray(c, dtype=float) for c in constants]
    Y = np.empty((n_pad, n_out))
    z = np.array(z0, dtype=float)
    if c_fn is not None:
        zn = np.empty_like(z)
        for s in range(0, n_pad, chunk):
            c_fn([z, *[P.ctypes.data + s * P.strides[0] for P in padded], *consts],
                 [zn, Y.ctypes.data + s * Y.strides[0]])
            z, zn = zn, z
    else:
        for s in range(0, n_pad, chunk):
            zs, ys = casadi_fn(z, *[P[s:s + chunk].T for P in padded], *consts)
            z = np.array(zs).ravel()
            Y[s:s + chunk] = np.array(ys).T
    return (Y[:n], z) if final_state else Y[:n]


class CFunction:
    """Direct ctypes call of a casadi-generated C function on numpy buffers (no copies).

    casadi's generated API is ``int f(const double** arg, double** res, casadi_int* iw,
    double* w, int mem)`` with work sizes from ``f_work``; dense matrices are
    column-major, so an (n, N) casadi matrix is an (N, n) C-ordered numpy array.
    """

    def __init__(self, lib: ctypes.CDLL, name: str, fn: ca.Function | None = None):
        self.fn = fn
        work = getattr(lib, name + "_work")
        szs = [ctypes.c_longlong() for _ in range(4)]
        work.argtypes = [ctypes.POINTER(ctypes.c_longlong)] * 4
        if work(*[ctypes.byref(s) for s in szs]) != 0:
            raise CompileError(f"{name}_work failed")
        self._sizes = tuple(s.value for s in szs)
        self._local = threading.local()
        self._call = getattr(lib, name)
        self._call.restype = ctypes.c_int
        self._call.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
        for what in ("n_in", "n_out"):
            f = getattr(lib, f"{name}_{what}")
            f.restype = ctypes.c_longlong
            setattr(self, what, int(f()))

    def _buffers(self):
        """Work memory of the calling thread: ctypes releases the GIL during the call, so threads
        (a Dask worker's, say) calling the same function at once must not share it."""
        b = getattr(self._local, "b", None)
        if b is None:
            sz_arg, sz_res, sz_iw, sz_w = self._sizes
            b = ((ctypes.c_void_p * max(sz_arg, 1))(), (ctypes.c_void_p * max(sz_res, 1))(),
                 np.zeros(max(sz_iw, 1), dtype=np.int64), np.zeros(max(sz_w, 1), dtype=np.float64))
            self._local.b = b
        return b

    def __call__(self, args: list, results: list) -> None:
        """``args``/``results`` are float64 C-contiguous arrays (or ctypes addresses) in casadi's layout."""
        arg, res, iw, w = self._buffers()
        for i, a in enumerate(args):
            arg[i] = a if isinstance(a, int) else a.ctypes.data
        for i, r in enumerate(results):
            res[i] = r if isinstance(r, int) else r.ctypes.data
        if self._call(arg, res, iw.ctypes.data, w.ctypes.data, 0) != 0:
            raise CompileError("compiled evstab function reported an error")


class CompiledPlant:
    """A plant, a parameter set and a sample time, ready to roll out fast.

    ``rollout(x0, cmd, w)`` integrates a whole run in chunks of :data:`CHUNK`
    samples per call; ``step(x, cmd, w)`` advances one sample (for loops closed
    in Python). ``backend`` is ``"c"`` (compiled) or ``"vm"`` (casadi VM).
    """

    def __init__(self, model: PlantModel, p: VehicleParams, dt: float, *, compile: bool = True):
        model.check_params(p)
        self.model, self.params, self.dt = model, p, float(dt)
        self.n_sub = rk4_substeps(model, p, dt)
        step, names = build_step(model, p, dt, self.n_sub)
        self.pvec = param_vector(p, names)
        acc = step.mapaccum("rollout_acc", CHUNK)
        mx = [ca.MX.sym(n, *step.size_in(i)) for i, n in enumerate(("x0", "cmd", "w", "p"))]
        mx[1] = ca.MX.sym("cmd", len(COMMANDS), CHUNK)
        mx[2] = ca.MX.sym("w", len(DISTURBANCES), CHUNK)
        # The parameter vector is passed once per chunk and repeated inside.
        chunk = ca.Function("rollout", mx, acc(mx[0], mx[1], mx[2], ca.repmat(mx[3], 1, CHUNK)),
                            ["x0", "cmd", "w", "p"], ["X", "Y"])
        src = source_digest()
        key = hashlib.sha256("|".join([CODE_VERSION, model.name, ",".join(names), repr(self.dt),
                                       str(self.n_sub), CASADI_VERSION, src]).encode()).hexdigest()[:20]
        lib = compile_library([step, chunk], key) if compile else None
        self.symbolic_step, self._step_fn, self._chunk_fn = step, step, chunk
        if lib is not None:
            dll = ctypes.CDLL(str(lib))
            self._c_step = CFunction(dll, "step", step)
            self._c_chunk = CFunction(dll, "rollout", chunk)
            self.backend = "c"
        else:
            self.backend = "vm"

    def step(self, x, cmd, w):
        """One sample: returns ``(x_next, y)`` as numpy arrays."""
        x = np.ascontiguousarray(x, dtype=float)
        if self.backend == "c":
            xn, y = np.empty(len(self.model.states)), np.empty(len(TRUTH))
            self._c_step([x, np.ascontiguousarray(cmd, dtype=float), np.ascontiguousarray(w, dtype=float),
                          self.pvec], [xn, y])
            return xn, y
        xn, y = self._step_fn(x, cmd, w, self.pvec)
        return np.array(xn).ravel(), np.array(y).ravel()

    def rollout(self, x0, cmd, w):
        """Integrate ``N`` samples; ``cmd`` is (4, N), ``w`` is (8, N) or (8,).

        Returns ``(X, Y)``: states (nx, N+1) including ``x0``, and truth outputs
        (len(TRUTH), N) at the start of each sample.
        """
        cmd = np.asarray(cmd, dtype=float)
        n = cmd.shape[1]
        w = np.asarray(w, dtype=float)
        if w.ndim == 1:
            w = np.repeat(w[:, None], n, axis=1)
        nx = len(self.model.states)
        if self.backend == "c":
            return self._rollout_c(np.asarray(x0, dtype=float), cmd, w, n, nx)
        X = np.empty((nx, n + 1))
        Y = np.empty((len(TRUTH), n))
        X[:, 0] = x0
        for start in range(0, n, CHUNK):
            stop = min(start + CHUNK, n)
            m = stop - start
            c_blk, w_blk = cmd[:, start:stop], w[:, start:stop]
            if m < CHUNK:  # pad the last chunk by holding the last input; padded samples are dropped
                c_blk = np.concatenate([c_blk, np.repeat(c_blk[:, -1:], CHUNK - m, axis=1)], axis=1)
                w_blk = np.concatenate([w_blk, np.repeat(w_blk[:, -1:], CHUNK - m, axis=1)], axis=1)
            xs, ys = self._chunk_fn(X[:, start], c_blk, w_blk, self.pvec)
            X[:, start + 1:stop + 1] = np.array(xs)[:, :m]
            Y[:, start:stop] = np.array(ys)[:, :m]
        return X, Y

    def _rollout_c(self, x0, cmd, w, n, nx):
        # Column-major (k, N) casadi matrices are (N, k) C-ordered numpy arrays.
        n_pad = -(-n // CHUNK) * CHUNK
        C = np.empty((n_pad, cmd.shape[0]))
        C[:n] = cmd.T
        C[n:] = cmd[:, -1]
        W = np.empty((n_pad, w.shape[0]))
        W[:n] = w.T
        W[n:] = w[:, -1]
        X = np.empty((n_pad + 1, nx))
        Y = np.empty((n_pad, len(TRUTH)))
        X[0] = x0
        row_c, row_w, row_x, row_y = (a.strides[0] for a in (C, W, X, Y))
        base_c, base_w, base_x, base_y = (a.ctypes.data for a in (C, W, X, Y))
        pv = self.pvec
        for start in range(0, n_pad, CHUNK):
            self._c_chunk([base_x + start * row_x, base_c + start * row_c, base_w + start * row_w, pv],
                          [base_x + (start + 1) * row_x, base_y + start * row_y])
        return X[:n + 1].T, Y[:n].T


@lru_cache(maxsize=32)
def _cached(model_name: str, p: VehicleParams, dt: float, compile: bool) -> CompiledPlant:
    from evstab.plants import get_plant
    return CompiledPlant(get_plant(model_name), p, dt, compile=compile)


def compiled_plant(model: PlantModel, p: VehicleParams, dt: float, *, compile: bool = True) -> CompiledPlant:
    """A (memoised) :class:`CompiledPlant` for this model, parameter set and sample time."""
    return _cached(model.name, p, float(dt), compile)
