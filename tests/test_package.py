"""One package: evstab and its parts as evstab.<part>, nothing else on the import path; the version."""

import subprocess
import sys
import zipfile
from importlib.metadata import version
from pathlib import Path

import pytest

import evstab

ROOT = Path(__file__).resolve().parents[1]


def test_version_is_the_installed_distributions(capsys):
    from evstab.toolkit.cli import main
    assert evstab.__version__ == version("evstab")
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == f"evstab {version('evstab')}"


def test_the_entry_points_a_script_needs():
    p = evstab.load_vehicle("compact-ev")
    assert isinstance(p, evstab.VehicleParams) and "compact-ev" in evstab.bundled_vehicles()
    r = evstab.simulate(p, "bicycle", evstab.make_maneuver("step-steer", p, 60 / 3.6))
    assert len(r.t) == 6000
    for name in evstab.__all__:
        assert getattr(evstab, name) is not None
    with pytest.raises(AttributeError):
        evstab.no_such_name  # noqa: B018


def test_only_evstab_is_importable_outside_the_source_tree(tmp_path):
    # from another folder (the source tree is not on sys.path there): the generic names are not
    # importable, evstab's parts are
    code = ("import importlib.util as u, evstab.plants, evstab.toolkit.cli, evstab.studies._common;"
            "print([n for n in ('plants', 'controllers', 'toolkit', 'studies') if u.find_spec(n) is not None])")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"


def test_the_wheel_holds_one_top_level_package(tmp_path):
    res = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(tmp_path), str(ROOT)],
                         capture_output=True, text=True, timeout=600)
    if res.returncode != 0:
        pytest.skip(f"cannot build a wheel here (no build backend from the package registry?): {res.stderr[-300:]}")
    wheel = next(tmp_path.glob("evstab-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {"evstab", f"evstab-{version('evstab')}.dist-info"}
    assert "evstab/plants/data/compact-ev.toml" in names and "evstab/toolkit/cli.py" in names


def test_the_formats_page_carries_the_codes_tables():
    # docs/formats.md's drive-log and vehicle tables are printed from the reader's schema and the
    # validator's fields: the page may not drift from them
    from evstab.toolkit.logs.formats import drive_log_table, vehicle_table
    page = (ROOT / "docs" / "formats.md").read_text()
    for row in (drive_log_table() + "\n" + vehicle_table()).splitlines():
        assert row in page, row


def test_readme_points_at_pages_that_exist():
    import re
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\((docs/[\w.-]+\.md)\)", text)
    assert len(links) >= 8 and all((ROOT / link).is_file() for link in links)
    for page in (ROOT / "docs").glob("*.md"):  # and the pages' links between themselves
        for link in re.findall(r"\]\(([\w.-]+\.md)\)", page.read_text()):
            assert (ROOT / "docs" / link).is_file(), (page.name, link)


def test_library_raises_only_typed_errors():
    # a user-facing error is an EvstabError subclass (the command line turns those into exit 2 with
    # the message); a bare ValueError/RuntimeError/Exception raised by the library would be a traceback
    import ast
    bare = {"ValueError", "RuntimeError", "Exception", "KeyError", "TypeError", "OSError", "AssertionError"}
    found = []
    for part in ("plants", "controllers", "toolkit", "studies"):
        for f in sorted((ROOT / part).rglob("*.py")):
            tree = ast.parse(f.read_text())
            protocol = {id(n) for fn in ast.walk(tree) if isinstance(fn, ast.FunctionDef) and
                        fn.name in ("__getitem__", "__getattr__") for n in ast.walk(fn)}  # KeyError there is the protocol
            for node in ast.walk(tree):
                if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and id(node) not in protocol and \
                        isinstance(node.exc.func, ast.Name) and node.exc.func.id in bare:
                    found.append(f"{f.relative_to(ROOT)}:{node.lineno} {node.exc.func.id}")
    assert not found, found
    import evstab.plants.errors as errors
    import evstab.toolkit.firmware.export  # noqa: F401 (defines ExportError)
    for cls in vars(errors).values():
        if isinstance(cls, type) and issubclass(cls, Exception):
            assert issubclass(cls, errors.EvstabError), cls


def test_the_public_api_has_numpydoc_with_every_parameter():
    # as python-control's docstring test does: every parameter of a public function is in its
    # "Parameters" section ("name : type"), and it says what it returns
    import inspect
    import re
    for name in evstab.__all__:
        obj = getattr(evstab, name, None)
        if not inspect.isfunction(obj):
            continue
        doc = inspect.getdoc(obj) or ""
        params = [p for p in inspect.signature(obj).parameters if p not in ("self", "args", "kwargs")]
        if params:
            assert "Parameters\n----------" in doc, name
            for p in params:
                assert re.search(rf"^{p}( :|, )|, {p} :", doc, flags=re.M), (name, p)
        assert "Returns\n-------" in doc, name
