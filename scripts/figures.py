"""The figures the README quotes, kept in one file that the benchmark scripts write.

`docs/figures.json` maps a key to one measured figure: the sentence the README shows, the
command that measured it, the date and the target. After a benchmark prints a figure, `set`
stores it (or a script calls `record`); `python scripts/figures.py` rewrites the README's
generated blocks from the file; `tests/test_docs.py` fails when the README and the file
disagree. So a figure in the README always has its command beside it.

    python scripts/figures.py            # rewrite README.md's generated blocks from docs/figures.json
    python scripts/figures.py --check    # exit 1 and name the block when README.md is out of date
    python scripts/figures.py set KEY --text "..." --command "..." [--target "..."] [--table NAME]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
FIGURES = ROOT / "docs" / "figures.json"
README = ROOT / "README.md"

# A generated block in README.md: <!-- figures:NAME --> ... <!-- /figures:NAME -->
BLOCK = re.compile(r"(<!-- figures:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- /figures:(?P=name) -->)", re.S)


def load(path: Path = FIGURES) -> dict[str, dict[str, Any]]:
    return json.loads(path.read_text()) if path.exists() else {}


def record(key: str, text: str, command: str, target: str = "-", *, values: dict[str, float] | None = None,
           table: str = "figures", path: Path = FIGURES) -> None:
    """Set one figure (atomically: the file is replaced whole). `text` is what the README shows;
    `values` keeps the raw numbers for tests and later comparisons; `table` names the README
    block the row belongs to."""
    figures = load(path)
    figures[key] = {"table": table, "text": text, "command": command, "target": target,
                    "values": values or {}, "date": datetime.date.today().isoformat()}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".figures-")
    with os.fdopen(fd, "w") as fh:
        json.dump(figures, fh, indent=1, sort_keys=True)
        fh.write("\n")
    os.replace(tmp, path)


def render(name: str, figures: dict[str, dict[str, Any]]) -> str:
    """The markdown of README block `name`: one table row per figure in that table, in key order."""
    rows = [f for _, f in sorted(figures.items()) if f.get("table") == name]
    lines = ["| figure | measured (date) | target | command |", "|---|---|---|---|"]
    for f in rows:
        lines.append(f"| {f['text']} | {f['date']} | {f['target']} | `{f['command']}` |")
    return "\n".join(lines) + "\n"


def refresh(text: str, figures: dict[str, dict[str, Any]]) -> str:
    """README text with every generated block rendered anew from `figures`."""
    return BLOCK.sub(lambda m: m.group(1) + render(m.group("name"), figures) + m.group(4), text)


def stale_blocks(text: str, figures: dict[str, dict[str, Any]]) -> list[str]:
    """Names of the README blocks whose text is not what the figures file renders."""
    return [m.group("name") for m in BLOCK.finditer(text) if m.group("body") != render(m.group("name"), figures)]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["set"]:
        return _set(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only check; exit 1 naming any stale block")
    args = ap.parse_args(argv)
    text, figures = README.read_text(), load()
    stale = stale_blocks(text, figures)
    if args.check:
        for name in stale:
            print(f"README.md block '{name}' differs from docs/figures.json: run python scripts/figures.py")
        return 1 if stale else 0
    if stale:
        README.write_text(refresh(text, figures))
    print(f"README.md: {len(stale)} block(s) rewritten from docs/figures.json")
    return 0


def _set(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="figures.py set", description="store one measured figure, then refresh README.md")
    ap.add_argument("key", help="the figure's key; rows sort by it")
    ap.add_argument("--text", required=True, help="what the README shows")
    ap.add_argument("--command", required=True, help="the command that printed the figure")
    ap.add_argument("--target", default="-", help="the target it is judged against")
    ap.add_argument("--table", default="figures", help="the README block the row belongs to (default figures)")
    args = ap.parse_args(argv)
    record(args.key, args.text, args.command, args.target, table=args.table)
    return main([])


if __name__ == "__main__":
    sys.exit(main())
