"""Every results table of the docs is a results block that names the file a study or a benchmark
writes and the command that writes it; ``python -m evstab.studies.publish`` fills the blocks from
those files. (The study tests check, for each study, that its quick run writes each file its blocks
name with the block's columns: :func:`evstab.studies.publish.check_study`.)"""

import importlib
import re
import shutil
from pathlib import Path

import pytest

from evstab.plants.errors import DataError
from evstab.studies import publish

ROOT = Path(__file__).resolve().parents[2]

# reference tables (formats, layout, symbols, the list of files): not results
REFERENCE = {
    "formats.md": ("column|unit|required|possible range", "key|meaning [unit]|required|range", "key|meaning"),
    "layout.md": ("where|what",),
    "models.md": ("symbol|name in code|meaning|unit|sign", "plant|what it has"),
    "firmware.md": ("file|what", "input|checked|a bad sample reads as"),
}


def test_every_results_table_is_a_block_with_a_producer():
    found = publish.blocks(ROOT)
    assert len(found) >= 20
    for b in found:
        name = Path(b.path).name
        if b.study is not None:
            src = Path(importlib.import_module(f"evstab.studies.{b.study}").__file__).read_text()
            assert f'"{name}"' in src, f"{b.study} does not write {name}"
        elif b.command.startswith("python -m evstab.toolkit."):  # a toolkit module's own report
            src = Path(importlib.import_module(b.command.split()[2]).__file__).read_text()
            assert f'"{name}"' in src, f"{b.command} does not write {name}"
        elif b.command.startswith("python benchmarks/"):
            script = ROOT / b.command.split()[1]
            assert script.is_file() and "--md" in script.read_text(), b.command
        else:
            assert b.command.startswith("evstab design") and name == "summary.md", b.command
        assert publish.table_header(b.body) is not None, f"{b.page.name}: block {b.path} has no table"
    # outside the blocks, only the reference tables
    for page in publish.pages(ROOT):
        text = publish.BLOCK.sub("", page.read_text())
        headers = {publish.table_header(t) for t in re.findall(r"(?m)^\|.*\|$\n^\|[-| :]+\|$", text)}
        assert headers <= set(REFERENCE.get(page.name, ())), (page.name, headers - set(REFERENCE.get(page.name, ())))


def test_publish_fills_every_block_or_writes_nothing(tmp_path):
    for page in publish.pages(ROOT):
        dest = tmp_path / page.relative_to(ROOT)
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(page, dest)
    found = publish.blocks(tmp_path)
    before = {p: p.read_text() for p in publish.pages(tmp_path)}
    # one table missing: an error naming it and its command, and no page touched
    for b in found[1:]:
        (tmp_path / b.path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / b.path).write_text(f"| a | b |\n| --- | --- |\n| {b.path} | 1 |\n")
    with pytest.raises(DataError, match=re.escape(found[0].path)):
        publish.publish(tmp_path)
    assert {p: p.read_text() for p in publish.pages(tmp_path)} == before
    (tmp_path / found[0].path).parent.mkdir(parents=True, exist_ok=True)
    (tmp_path / found[0].path).write_text("| a | b |\n| --- | --- |\n| first | 1 |\n")
    written = publish.publish(tmp_path)
    assert written
    after = publish.blocks(tmp_path)
    assert len(after) == len(found)
    for b in after:
        assert b.body.startswith(f"Made by `{b.command}`.") and publish.table_header(b.body) == "a|b"
    # publishing again changes nothing
    assert publish.publish(tmp_path) == []
