"""Write the results tables the studies and benchmarks made into the docs pages.

``python -m evstab.studies.publish [--root DIR]`` replaces the body of every results block of
``docs/*.md`` and ``README.md``::

    <!-- results: out/studies/robustness.md | python -m evstab.studies.estimation_robustness out/studies -->
    ...
    <!-- /results -->

with the Markdown table in the named file (relative to the root), under a line saying the command
that made it. Run the commands first (each block names its own); the pages are written only when
every block's table exists (each page to a temporary name, then renamed).
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass
from pathlib import Path

from evstab.plants.errors import DataError
from evstab.toolkit.logs.drivelog import atomic_write

BLOCK = re.compile(r"<!-- results: (?P<path>[^|>]+?) \| (?P<command>[^>]+?) -->\n(?P<body>.*?)<!-- /results -->",
                   re.S)


@dataclass(frozen=True)
class Block:
    page: Path
    path: str
    """The table's file, relative to the root."""
    command: str
    body: str

    @property
    def study(self) -> str | None:
        """The study module the command runs (None for a benchmark or an ``evstab`` command)."""
        m = re.match(r"python -m evstab\.studies\.(\w+)", self.command)
        return m.group(1) if m else None


def pages(root: Path) -> list[Path]:
    return sorted((root / "docs").glob("*.md")) + [root / "README.md"]


def blocks(root: Path) -> list[Block]:
    """Every results block of the docs pages."""
    out = []
    for page in pages(root):
        for m in BLOCK.finditer(page.read_text()):
            out.append(Block(page, m["path"].strip(), m["command"].strip(), m["body"]))
    return out


def body(command: str, table: str) -> str:
    return f"Made by `{command}`.\n\n{table.rstrip()}\n"


def table_header(text: str) -> str | None:
    """The first Markdown table row of ``text`` (its column names), cells stripped."""
    for line in text.splitlines():
        if line.startswith("|"):
            return "|".join(c.strip() for c in line.strip().strip("|").split("|"))
    return None


def check_study(study: str, out: Path, root: Path | None = None) -> list[str]:
    """What is wrong with the output ``out`` of a (quick) run of ``study`` for the docs blocks it
    makes: a block's file it did not write, or wrote with other columns than the block shows."""
    root = Path(__file__).resolve().parents[1] if root is None else root
    problems = []
    for b in blocks(root):
        if b.study != study:
            continue
        made = Path(out) / Path(b.path).name
        if not made.is_file():
            problems.append(f"{study} did not write {made.name} ({b.page.name} shows it)")
        elif table_header(made.read_text()) != table_header(b.body):
            problems.append(f"{made.name}: columns {table_header(made.read_text())!r}, {b.page.name} shows "
                            f"{table_header(b.body)!r}")
    return problems


def publish(root: Path, only: tuple[str, ...] = ()) -> list[Path]:
    """Rewrite the results blocks under ``root`` (with ``only``, the blocks of those files); returns the
    pages written."""
    found = [b for b in blocks(root) if not only or b.path in only]
    missing = [b for b in found if not (root / b.path).is_file()]
    if missing:
        raise DataError("no table for these results blocks (run their commands first):\n" + "\n".join(
            f"  {b.page.relative_to(root)}: {b.path} <- {b.command}" for b in missing))
    written = []
    for page in pages(root):
        text = page.read_text()

        def fill(m):
            path, command = m["path"].strip(), m["command"].strip()
            if only and path not in only:
                return m.group(0)
            table = (root / path).read_text()
            return f"<!-- results: {path} | {command} -->\n{body(command, table)}<!-- /results -->"

        new = BLOCK.sub(fill, text)
        if new != text:
            atomic_write(page, lambda fh, s=new: fh.write(s))
            written.append(page)
    return written


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(prog="python -m evstab.studies.publish", description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", default=".", help="the repository root (default: the current folder)")
    ap.add_argument("--only", nargs="+", default=(), metavar="FILE",
                    help="fill only the blocks of these tables (paths as the blocks name them)")
    args = ap.parse_args(argv)
    root = Path(args.root)
    try:
        written = publish(root, tuple(args.only))
    except DataError as e:
        print(f"publish: {e}", file=sys.stderr)
        return 2
    for p in written:
        print(f"wrote {p}")
    print(f"{len(blocks(root))} results blocks, {len(written)} pages changed")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
