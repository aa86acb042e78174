"""The exported C on a single-precision-FPU microcontroller: the worst-stack reader on hand-built
call graphs, the cross-compile for Cortex-M7 and Cortex-R5 (strict, -Werror), and cppcheck's MISRA
C:2012 addon against the deviations the docs list.

The cross-compile needs Debian's gcc-arm-none-eabi and libnewlib-arm-none-eabi, the MISRA check
cppcheck; ``.ci/run`` installs them, elsewhere those tests skip and say which is missing.
"""


import pytest

from evstab.toolkit.firmware import mcu
from evstab.toolkit.firmware.export import export_design


def _graph(nodes, edges):
    """A -fcallgraph-info=su graph in gcc's VCG text: nodes {name: (bytes, qualifier) or None}."""
    out = ['graph: { title: "x.c"']
    for name, frame in nodes.items():
        label = (f"{name}\\nx.c:1:1\\n{frame[0]} bytes ({frame[1]})" if frame else f"{name}\\nmath.h:1:1")
        out.append(f'node: {{ title: "x.c:{name}" label: "{label}" }}' if frame else
                   f'node: {{ title: "{name}" label: "{label}" shape : ellipse }}')
    for a, b in edges:
        out.append(f'edge: {{ sourcename: "x.c:{a}" targetname: "{b if nodes[b] is None else "x.c:" + b}" '
                   f'label: "x.c:2:3" }}')
    return "\n".join(out + ["}"])


def test_worst_stack_is_the_deepest_sum_of_frames():
    # step 100 -> guard 40 -> sqrtf (library), step -> fix 300 -> lerp 16, step -> nofix 250 -> lerp:
    # the deepest chain is step, fix, lerp: 100 + 300 + 16 = 416 (the library call counts 0)
    nodes = {"evstab_step": (100, "static"), "guard": (40, "static"), "fix": (300, "static"),
             "nofix": (250, "static"), "lerp": (16, "static"), "sqrtf": None}
    edges = [("evstab_step", "guard"), ("guard", "sqrtf"), ("evstab_step", "fix"), ("fix", "lerp"),
             ("evstab_step", "nofix"), ("nofix", "lerp")]
    total, path, ext, frames = mcu.worst_stack(_graph(nodes, edges))
    assert total == 416 and path == ("evstab_step", "fix", "lerp")
    assert ext == ("sqrtf",) and frames["guard"] == (40, "static")
    # one byte more on the guard's chain than the fix's turns the answer (the boundary): 100 + 317
    nodes["guard"] = (317, "static")
    total, path, _, _ = mcu.worst_stack(_graph(nodes, edges))
    assert total == 417 and path[:2] == ("evstab_step", "guard")


def test_worst_stack_refuses_what_has_no_bound():
    nodes = {"evstab_step": (100, "static"), "a": (8, "dynamic,bounded")}
    with pytest.raises(mcu.McuError, match="static bound"):
        mcu.worst_stack(_graph(nodes, [("evstab_step", "a")]))
    nodes = {"evstab_step": (100, "static"), "a": (8, "static")}
    with pytest.raises(mcu.McuError, match="recursion"):
        mcu.worst_stack(_graph(nodes, [("evstab_step", "a"), ("a", "evstab_step")]))


@pytest.fixture(scope="module")
def exported(default_design_dir, tmp_path_factory):
    root = tmp_path_factory.mktemp("mcu")
    for precision in ("float32", "float64"):
        export_design(default_design_dir, root / precision, ("c",), precision)
    return root


@pytest.mark.skipif(mcu.arm_toolchain() is None, reason="no arm-none-eabi-gcc (Debian: gcc-arm-none-eabi)")
@pytest.mark.parametrize("target", list(mcu.TARGETS))
def test_the_step_cross_compiles_clean_with_bounded_stack_and_no_double_arithmetic(exported, target, tmp_path):
    f32 = mcu.build(exported / "float32", target, tmp_path / "f32")  # -Werror with -Wdouble-promotion
    f64 = mcu.build(exported / "float64", target, tmp_path / "f64")
    # on a single-precision FPU, float32 uses no software double routine and only the float libm;
    # float64 needs them (so the check sees them when they are there)
    assert f32.double_routines == () and "__aeabi_dadd" in f64.double_routines
    assert all(f.endswith("f") for f in f32.external_calls if not f.startswith("mem")), f32.external_calls
    for b in (f32, f64):
        assert b.stack_path[0] == "evstab_step"
        assert b.worst_stack == sum(b.frames.get(f, (0, ""))[0] for f in b.stack_path)
        # the filter's 121-number state lives in the caller's evstab_state_t, not on the stack: the
        # step fits a 2 KiB task stack in float32 and 4 KiB in float64 (measured 1.1 and 2.3 KiB;
        # a frame holding a copy of the state or of a full covariance would not)
        assert 0 < b.worst_stack <= (2048 if b is f32 else 4096)
        assert b.bss == 0  # no mutable globals
    # float32 halves every real: the code and the calibration data shrink
    assert f32.data * 2 == f64.data and f32.text < f64.text


@pytest.mark.skipif(mcu.cppcheck() is None, reason="no cppcheck (Debian: cppcheck)")
def test_misra_findings_are_the_documented_deviations(exported):
    rules = mcu.misra(exported / "float32" / "evstab_firmware.c")
    assert rules, "the addon ran and found nothing: the deviations the docs list would be stale"
    undocumented = set(rules) - set(mcu.DEVIATIONS)
    assert not undocumented, f"MISRA C:2012 rules reported without a deviation in toolkit.firmware.mcu: {undocumented}"
