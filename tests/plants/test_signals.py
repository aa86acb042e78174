"""The named signal layouts: packing and unpacking for numpy and casadi, and the rule that no library
code indexes a signal vector by position."""

import ast
import pathlib

import casadi as ca
import numpy as np
import pytest

from evstab.plants.backend import CASADI, NUMPY
from evstab.plants.errors import ModelError
from evstab.plants.signals import Layout, Signal, join

LAY = Layout("test", [Signal("a", "m"), Signal("blk", "-", size=3), Signal("b", "rad", default=2.0),
                      Signal("opt", "-", optional=True)])


def test_offsets_slots_and_sizes():
    assert tuple(LAY) == ("a", "blk", "b", "opt") and LAY.size == 6
    assert [LAY.index(k) for k in LAY] == [0, 1, 4, 5]
    assert LAY.slot("blk") == slice(1, 4) and LAY.span("blk", "b") == slice(1, 5)
    assert LAY.offsets() == {"a": 0, "blk": 1, "b": 4, "opt": 5, "size": 6}
    assert LAY.units == ("m", "-", "rad", "-")
    j = join("both", ("x", LAY), ("y", Layout("s", ["c"])))
    assert tuple(j)[-1] == "y.c" and j.size == 7


def test_numpy_pack_unpack_round_trip_and_batches():
    v = LAY.pack(a=1.0, blk=np.array([3.0, 4.0, 5.0]), opt=7.0)
    np.testing.assert_array_equal(v, [1.0, 3.0, 4.0, 5.0, 2.0, 7.0])  # b took its default
    s = LAY.unpack(v)
    assert s.a == 1.0 and s.b == 2.0 and s.opt == 7.0
    np.testing.assert_array_equal(s.blk, [3.0, 4.0, 5.0])
    # a trailing optional entry not given is left off, and reads as None
    short = LAY.pack(a=1.0, blk=np.zeros(3), b=0.5)
    assert short.shape == (5,) and LAY.unpack(short).opt is None
    # N cases at once: rows of an (n, N) array
    V = np.tile(v[:, None], (1, 4))
    assert LAY.unpack(V).a.shape == (4,)
    # (N, n) tables: columns are views
    T = LAY.zeros(3)
    LAY.columns(T)["b"][:] = 9.0
    assert np.all(T[:, 4] == 9.0)


def test_casadi_pack_unpack_round_trip():
    x = ca.SX.sym("x", LAY.size)
    s = LAY.unpack(x)
    v = LAY.pack(vars(s), CASADI)
    f = ca.Function("f", [x], [v])
    val = np.arange(6.0)
    np.testing.assert_array_equal(np.array(f(val)).ravel(), val)
    assert LAY.pack({"a": s.a, "blk": s.blk}, CASADI, fill=0.0).shape == (5, 1)


def test_errors_name_the_layout_and_the_entry():
    with pytest.raises(ModelError, match="layout 'test'.*expected a vector of 6"):
        LAY.unpack(np.zeros(3))
    with pytest.raises(ModelError, match="no entries zz"):
        LAY.pack(a=1.0, zz=2.0)
    with pytest.raises(ModelError, match="entry 'blk' not given"):
        LAY.pack(a=1.0, b=1.0)
    with pytest.raises(ModelError, match="no entry 'zz'"):
        LAY.index("zz")
    with pytest.raises(ModelError, match="named twice"):
        Layout("dup", ["a", "a"])
    with pytest.raises(ModelError, match="table of 6 columns"):
        LAY.columns(np.zeros((2, 5)))
    assert NUMPY is not None


# names that hold signal vectors in the library (inputs, outputs, states, signals, tables of them)
_VECTORS = {"u", "y", "z", "sig", "cmd", "meas", "extra", "theta", "U", "Y", "E", "M", "zs", "z_next", "law", "av",
            "applied", "flags", "slots", "inp", "g"}
# the multi-body plant's right-hand side mirrors CommonRoad's vehicle_dynamics_mb line by line (its
# state and input vectors are the package's, indexed as the package does: the test against the package
# compares them entry by entry)
_EXEMPT = {("plants/commonroad_mb.py", "u")}


def _positional(node) -> bool:
    def is_int(s):
        return isinstance(s, ast.Constant) and isinstance(s.value, int) and not isinstance(s.value, bool)

    def bad(s):
        return is_int(s) or (isinstance(s, ast.Slice) and (is_int(s.lower) or is_int(s.upper)))

    sl = node.slice
    return bad(sl) or (isinstance(sl, ast.Tuple) and any(bad(e) for e in sl.elts))


def test_no_library_code_indexes_a_signal_vector_by_position():
    root = pathlib.Path(__file__).resolve().parents[2]
    found = []
    for folder in ("plants", "controllers", "toolkit"):
        for path in sorted((root / folder).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) and \
                        node.value.id in _VECTORS and (rel, node.value.id) not in _EXEMPT and _positional(node):
                    found.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
    assert not found, "positional signal indexing (use the layout):\n" + "\n".join(found)
