"""The exported C on a microcontroller: a cross-compile for single-precision-FPU targets, its code
size and worst-case stack, and cppcheck's MISRA C:2012 addon over it.

``python -m evstab.toolkit.firmware.mcu OUT`` exports the bundled ``compact-ev`` design (or
``--design DIR``) in float32 and float64, builds each for every target in :data:`TARGETS` with
``arm-none-eabi-gcc`` (Debian's ``gcc-arm-none-eabi``), and writes the docs' tables
``mcu_build.md`` and ``mcu_misra.md`` to OUT.

- **Size**: ``arm-none-eabi-size`` of the step's object (text, data, bss), and the growth of a linked
  image (newlib, ``-specs=nosys.specs``, ``--gc-sections``) when a ``main`` that only returns is
  replaced by one that calls ``evstab_init`` and ``evstab_step``: the step plus the C library
  routines it pulls in (libm, memcpy, and in float64 on these FPUs the double-precision software
  arithmetic ``__aeabi_d*``).
- **Stack**: gcc's ``-fcallgraph-info=su`` call graph with each function's frame; the worst path
  from ``evstab_step`` is the largest sum of frames along a call chain. Every frame must be
  ``static`` (no variable-length array, no ``alloca``); the C library's frames are not in the graph
  and are named beside the figure.
- **Double precision**: the float32 object must reference no ``__aeabi_d*`` routine (no double
  arithmetic on a single-precision FPU) and compile clean with ``-Wdouble-promotion``.
- **MISRA**: cppcheck's ``misra`` addon (rule numbers only: the rule texts are licensed and not
  shipped) over the float32 source; each rule reported is counted.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from evstab.plants.errors import EvstabError

ARM_CC = "arm-none-eabi-gcc"
STRICT = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wdouble-promotion", "-Wconversion")
# Cortex-M7 with the single-precision FPv5 unit (e.g. STM32F7 parts without the DP option) and
# Cortex-R5 with the single-precision VFPv3 (vfpv3xd): the classes of MCU a chassis ECU runs on.
TARGETS = {
    "cortex-m7": ("-mcpu=cortex-m7", "-mthumb", "-mfpu=fpv5-sp-d16", "-mfloat-abi=hard"),
    "cortex-r5": ("-mcpu=cortex-r5", "-marm", "-mfpu=vfpv3xd", "-mfloat-abi=hard"),
}
OPT = "-O2"

_MAIN = """#include "evstab_firmware.h"
static evstab_state_t s;
static evstab_input_t in;
static evstab_output_t out;
int main(void)
{
#ifdef EVSTAB_CALL_STEP
    evstab_init(&s);
    evstab_step(&s, &in, &out);
    return (int)out.steer_cmd;
#else
    return (int)sizeof s + (int)sizeof in + (int)sizeof out;
#endif
}
"""


class McuError(EvstabError, RuntimeError):
    """The cross-compile or the MISRA check cannot run or failed (the tool's message is named)."""


def arm_toolchain() -> str | None:
    """The ARM cross-compiler's path, or None when it is not installed."""
    return shutil.which(ARM_CC)


def cppcheck() -> str | None:
    return shutil.which("cppcheck")


def _run(argv, cwd=None) -> str:
    argv = [str(a) for a in argv]
    out = subprocess.run(argv, capture_output=True, text=True, cwd=cwd)
    if out.returncode != 0:
        tool = Path(argv[0]).name
        raise McuError(f"{tool} failed ({out.returncode}): {' '.join(argv)}\n{(out.stderr or out.stdout)[-3000:]}")
    return out.stdout + out.stderr


@dataclass
class McuBuild:
    """One exported C source built for one target."""
    target: str
    precision: str
    text: int  # bytes of code and read-only data in the step's object
    data: int  # initialised data (the calibration objects, kept in memory for the A2L)
    bss: int
    linked_growth: int  # bytes the step adds to a linked image, C library routines included
    worst_stack: int  # bytes, the step's own frames along the deepest call chain
    stack_path: tuple[str, ...]
    external_calls: tuple[str, ...]  # C library functions called (frames not in the figure)
    double_routines: tuple[str, ...]  # __aeabi_d* software double routines referenced
    frames: dict = field(default_factory=dict)  # function -> (bytes, qualifier)


def worst_stack(ci_text: str, root: str = "evstab_step") -> tuple[int, tuple[str, ...], tuple[str, ...], dict]:
    """Worst stack from a ``-fcallgraph-info=su`` graph: (bytes, the chain, externals, frames).

    Nodes of functions defined in the unit carry ``N bytes (static)``; a callee without a frame
    (a library function) counts 0 and is listed as external. A recursive chain, or a frame that is
    not ``static``, has no bound and raises :class:`McuError`.
    """
    frames: dict = {}
    edges: dict = {}
    external: set = set()
    for m in re.finditer(r'node: \{ title: "([^"]+)" label: "([^"]*)"', ci_text):
        title, label = m.groups()
        name = title.rsplit(":", 1)[-1]
        fm = re.search(r"\\n(\d+) bytes \(([^)]*)\)", label)
        if fm:
            frames[name] = (int(fm.group(1)), fm.group(2))
        else:
            external.add(name)
    for m in re.finditer(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', ci_text):
        src, dst = (s.rsplit(":", 1)[-1] for s in m.groups())
        edges.setdefault(src, set()).add(dst)
    unbounded = {f: q for f, (_, q) in frames.items() if q != "static"}
    if unbounded:
        raise McuError(f"stack frames without a static bound: {unbounded}")
    if root not in frames:
        raise McuError(f"{root} not in the call graph")

    def deepest(f, chain):
        if f in chain:
            raise McuError(f"recursion: {' -> '.join(chain + (f,))}")
        own = frames.get(f, (0, "static"))[0]
        best, path = 0, ()
        for g in sorted(edges.get(f, ())):
            b, p = deepest(g, chain + (f,))
            if b > best or not path:
                best, path = b, p
        return own + best, (f,) + path

    total, path = deepest(root, ())
    called = set()
    stack = [root]
    while stack:
        f = stack.pop()
        for g in edges.get(f, ()):
            if g not in called:
                called.add(g)
                stack.append(g)
    return total, path, tuple(sorted(called & external)), frames


def _size(obj: Path) -> tuple[int, int, int]:
    line = _run(["arm-none-eabi-size", obj]).splitlines()[-1].split()
    return int(line[0]), int(line[1]), int(line[2])


def build(source_dir, target: str, out_dir, extra_flags=()) -> McuBuild:
    """Cross-compile ``evstab_firmware.c`` of an export folder for ``target`` (strict, -Werror)."""
    if arm_toolchain() is None:
        raise McuError(f"{ARM_CC} is not installed (Debian: apt-get install gcc-arm-none-eabi "
                       f"libnewlib-arm-none-eabi)")
    if target not in TARGETS:
        raise McuError(f"unknown target {target!r}; known: {', '.join(TARGETS)}")
    src = Path(source_dir) / "evstab_firmware.c"
    header = (Path(source_dir) / "evstab_firmware.h").read_text()
    precision = "float32" if re.search(r"typedef\s+float\s+evstab_real", header) else "float64"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    flags = (*STRICT, OPT, *TARGETS[target], *extra_flags)
    obj = out / f"{target}.o"
    _run([ARM_CC, *flags, "-ffunction-sections", "-fdata-sections", "-fstack-usage", "-fcallgraph-info=su",
          "-c", "-o", obj, src])
    text, data, bss = _size(obj)
    total, path, ext, frames = worst_stack((out / f"{target}.ci").read_text())
    undefined = _run(["arm-none-eabi-nm", "-u", obj]).split()
    doubles = tuple(sorted(s for s in undefined if s.startswith("__aeabi_d") or s.startswith("__aeabi_i2d")))
    main = out / "main.c"
    main.write_text(_MAIN)
    linked = []
    for defs in ((), ("-DEVSTAB_CALL_STEP",)):
        elf = out / f"{target}{'_step' if defs else '_empty'}.elf"
        objs = [obj] if defs else []
        _run([ARM_CC, *TARGETS[target], OPT, *defs, "-I", source_dir, "-specs=nosys.specs", "-Wl,--gc-sections",
              "-o", elf, main, *objs, "-lm"])
        linked.append(sum(_size(elf)[:2]))
    return McuBuild(target, precision, text, data, bss, linked[1] - linked[0], total, path, ext, doubles, frames)


# cppcheck's own notes, not findings: more preprocessor configurations than --max-configs checks
# (the header's optional #ifdefs; the default configuration is the one checked)
_NOT_RULES = (":toomanyconfigs", ":missingIncludeSystem", ":checkersReport")


def misra(source: Path, timeout: float = 900.0) -> Counter:
    """MISRA C:2012 rules cppcheck's addon reports on ``source``: rule -> number of places."""
    if cppcheck() is None:
        raise McuError("cppcheck is not installed (Debian: apt-get install cppcheck)")
    cmd = ["cppcheck", "--addon=misra", "--std=c99", "--quiet", "--max-configs=1",
           "--template={file}:{line}:{id}", str(source)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if out.returncode != 0:
        raise McuError(f"cppcheck failed ({out.returncode}): {out.stderr[-2000:]}")
    rules: Counter = Counter()
    for line in out.stderr.splitlines():
        m = re.search(r":misra-c2012-(\d+\.\d+)$", line.strip())
        if m:
            rules[m.group(1)] += 1
        elif line.strip() and not line.strip().endswith(_NOT_RULES):
            raise McuError(f"cppcheck reported something other than a MISRA rule: {line}")
    return rules


# Why each reported rule is a deviation and not fixed (the docs' table prints this column).
DEVIATIONS = {
    "2.5": "the header's constants `EVSTAB_CONTROL_PERIOD` and `EVSTAB_DESIGN_DIGEST` are for the code "
           "that calls the step (its task period, the design it was built from); the step does not use them",
    "8.9": "the calibration objects (the schedule's rows) stay at file scope so the A2L and the linker's map "
           "locate them by name; the transition table and the initial state sit beside them; each is read by one "
           "function",
}


def report(design_dir, out_dir) -> tuple[list, Counter]:
    """Every target and precision built; MISRA over the float32 source. Writes nothing but build files."""
    from .export import export_design
    builds = []
    out = Path(out_dir)
    for precision in ("float32", "float64"):
        src = out / precision
        export_design(design_dir, src, ("c",), precision)
        for target in TARGETS:
            builds.append(build(src, target, src / target))
    return builds, misra(out / "float32" / "evstab_firmware.c")


def main(argv=None) -> None:
    import argparse
    import json
    import tempfile

    from evstab.studies._common import write_markdown

    from ..design.design_job import default_design_document
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="folder for the tables mcu_build.md and mcu_misra.md")
    ap.add_argument("--design", help="an 'evstab design' folder (default: the bundled compact-ev, dakf, 2-DOF)")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="evstab_mcu_"))
    design = args.design
    if design is None:
        doc = default_design_document("python -m evstab.toolkit.firmware.mcu")
        design = tmp / "design"
        design.mkdir()
        (design / "design.json").write_text(json.dumps(doc))
    builds, rules = report(design, tmp / "build")
    print(_run([ARM_CC, "--version"]).splitlines()[0], OPT, " ".join(STRICT))
    rows = []
    for b in builds:
        libc = [f for f in b.external_calls if not f.startswith("__aeabi_")]
        rows.append([b.target, b.precision, f"{b.text:,}", f"{b.data:,}", f"{b.bss:,}", f"{b.linked_growth:,}",
                     f"{b.worst_stack:,}", " > ".join(b.stack_path), ", ".join(libc),
                     f"{len(b.double_routines)} (`{b.double_routines[0]}`, ...)" if b.double_routines else "none"])
        print(f"{b.target} {b.precision}: text {b.text} data {b.data} bss {b.bss}; linked +{b.linked_growth}; "
              f"stack {b.worst_stack} ({' > '.join(b.stack_path)}); calls {', '.join(b.external_calls)}; "
              f"double routines: {len(b.double_routines)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_markdown(out / "mcu_build.md", [
        "target", "precision", "text [B]", "data [B]", "bss [B]", "linked image grows by [B]",
        "worst stack [B]", "deepest chain", "C library calls (frames not counted)", "software double routines"],
        rows)
    write_markdown(out / "mcu_misra.md", ["MISRA C:2012 rule", "places", "why it stands"],
                   [[r, str(n), DEVIATIONS.get(r, "not yet reviewed")] for r, n in
                    sorted(rules.items(), key=lambda kv: tuple(int(x) for x in kv[0].split(".")))])
    print("MISRA C:2012 (cppcheck addon, float32 source): " + ", ".join(f"{r} x{n}" for r, n in sorted(rules.items())))


if __name__ == "__main__":
    main()
