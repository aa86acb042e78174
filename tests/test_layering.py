"""The house's layering, counted from the imports (every ``import`` and ``from ... import`` in the source, at
module level or inside a function, read with ast): no module imports one that imports it back, directly or
round a circle, and no room imports a room above it.

The rooms, from the ground up (docs/layout.md): ``plants``; ``controllers``; ``toolkit.kernels`` and
``toolkit.logs`` (neither imports the other); ``toolkit.estimation``; ``toolkit.ecu``; ``toolkit.loop``;
``toolkit.verdicts``; ``toolkit.design``; ``toolkit.firmware`` and ``toolkit.cli_types``; ``toolkit.cli_logs`` (the
commands that read drive logs); ``toolkit.cli``. A
module may import its own room and the rooms below it.
"""

import ast
from pathlib import Path

import pytest

TOP = Path(__file__).resolve().parent.parent
PARTS = {"plants": "evstab.plants", "controllers": "evstab.controllers", "toolkit": "evstab.toolkit"}
FLOORS = [("plants",), ("controllers",), ("toolkit.kernels", "toolkit.logs"), ("toolkit.estimation",),
          ("toolkit.ecu",), ("toolkit.loop",), ("toolkit.verdicts",), ("toolkit.design",),
          ("toolkit.firmware", "toolkit.cli_types"), ("toolkit.cli_logs",), ("toolkit.cli",)]
FLOOR = {room: k for k, rooms in enumerate(FLOORS) for room in rooms}


def modules() -> dict:
    out = {}
    for part, pkg in PARTS.items():
        for f in sorted((TOP / part).rglob("*.py")):
            rel = f.relative_to(TOP / part).with_suffix("").parts
            out[".".join((pkg,) + (rel[:-1] if rel[-1] == "__init__" else rel))] = f
    return out


MODULES = modules()


def _known(name: str) -> str | None:
    """The module of ours that ``name`` is or lies in (a name imported from a module), or None."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports(name: str, path: Path) -> set:
    """The modules of ours that module ``name`` imports: a name imported from a package that is a submodule
    counts as that submodule (``from . import kalman``), anything else as the module named."""
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    deps = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            deps.update(_known(a.name) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            for a in node.names:
                deps.add(mod + "." + a.name if mod + "." + a.name in MODULES else _known(mod))
    deps.discard(None)
    deps.discard(name)
    return deps


GRAPH = {name: imports(name, path) for name, path in MODULES.items()}


def room(module: str) -> str:
    """``plants``, ``controllers``, or ``toolkit.<folder or module>``."""
    parts = module.split(".")
    return parts[1] if parts[1] != "toolkit" else "toolkit." + parts[2] if len(parts) > 2 else "toolkit"


def circles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_circles_are_found_by_hand():
    """The detector on hand-drawn graphs: a two-module circle, a three-module one beside a chain, none."""
    assert circles({"a": {"b"}, "b": {"a"}}) == [["a", "b"]]
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert circles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_the_reader_sees_function_level_and_package_imports():
    """Against the source: the design job imports the limits inside functions, the estimators' runner imports
    kalman as ``from . import kalman`` (the submodule, not the package), and the loop imports the ECU step."""
    assert "evstab.toolkit.design.limits" in GRAPH["evstab.toolkit.design.design_job"]
    assert "evstab.toolkit.estimation.kalman" in GRAPH["evstab.toolkit.estimation.runner"]
    assert "evstab.toolkit.estimation" not in GRAPH["evstab.toolkit.estimation.runner"]
    assert "evstab.toolkit.ecu.step" in GRAPH["evstab.toolkit.loop.closed_loop"]


def test_no_module_imports_one_that_imports_it_back():
    assert circles(GRAPH) == []


def test_every_module_lies_in_a_room_of_the_plan():
    assert {room(m) for m in MODULES} - set(FLOOR) == {"toolkit"}  # the toolkit package's own __init__


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_import_runs_up_a_floor(module):
    here = room(module)
    if here == "toolkit":
        return
    for dep in sorted(GRAPH[module]):
        there = room(dep)
        assert there == here or FLOOR.get(there, -1) < FLOOR[here], \
            f"{module} ({here}, floor {FLOOR[here]}) imports {dep} ({there}, floor {FLOOR.get(there)})"
