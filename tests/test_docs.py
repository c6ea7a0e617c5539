"""Docs that cannot drift: every code block in README.md and docs/ is checked against the code.

- `python` blocks run (from the checkout's root, in a fresh namespace). A block that states an
  API as stubs (`python contract=module:Name`) is checked instead: each `def` in it must be an
  attribute of that object with the same parameter names.
- `bash` / `console` blocks: every `gma-ffc ...` line is parsed by the real argument parser, every
  `python scripts/X.py` or `python -m M` line names a file or module that exists and flags its
  `--help` lists, and every `./scripts/X` exists and is executable.
- `yaml`, `json` and `toml` blocks parse; a `yaml` block that is a controller-config fragment
  validates as part of config/sim.yaml.
- `text` blocks (diagrams, equations, printed output) are prose. A fence must say which it is.
- The README's generated figure blocks equal what docs/figures.json renders (scripts/figures.py).
"""

from __future__ import annotations

import ast
import functools
import importlib
import inspect
import json
import re
import shlex
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md")),
        ROOT / "hil_sim" / "emulators" / "README.md", ROOT / "scripts" / "unseen" / "README.md"]
LANGUAGES = {"python", "bash", "console", "yaml", "json", "toml", "text"}


@dataclass(frozen=True)
class Block:
    path: Path
    line: int
    lang: str
    options: tuple[str, ...]
    text: str

    def __str__(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line} ({self.lang})"


def blocks_of(path: Path) -> list[Block]:
    out, lines, i = [], path.read_text().splitlines(), 0
    while i < len(lines):
        fence = re.match(r"^(\s*)```(.*)$", lines[i])
        if not fence:
            i += 1
            continue
        info = fence.group(2).split()
        body, j = [], i + 1
        while j < len(lines) and not lines[j].strip().startswith("```"):
            body.append(lines[j][len(fence.group(1)):])
            j += 1
        out.append(Block(path, i + 1, info[0] if info else "", tuple(info[1:]), "\n".join(body) + "\n"))
        i = j + 1
    return out


ALL = [b for p in DOCS if p.exists() for b in blocks_of(p)]


def of(*langs: str) -> list[Block]:
    return [b for b in ALL if b.lang in langs]


def test_every_fence_says_what_it_holds():
    unnamed = [str(b) for b in ALL if b.lang not in LANGUAGES]
    assert not unnamed, f"fences without one of {sorted(LANGUAGES)}: {unnamed}"


# ---- python ------------------------------------------------------------------------------
def _contract_target(b: Block) -> object | None:
    spec = dict(o.split("=", 1) for o in b.options if "=" in o).get("contract")
    if spec is None:
        return None
    module, _, name = spec.partition(":")
    obj: object = importlib.import_module(module)
    for part in filter(None, name.split(".")):          # `contract=module` alone: the module's functions
        obj = getattr(obj, part)
    return obj


@pytest.mark.parametrize("block", of("python"), ids=str)
def test_python_blocks_run_or_match_their_contract(block: Block, monkeypatch: pytest.MonkeyPatch):
    tree = ast.parse(block.text, filename=str(block))
    target = _contract_target(block)
    if target is None:
        monkeypatch.chdir(ROOT)
        monkeypatch.setattr(sys, "argv", [str(block)])
        exec(compile(tree, str(block), "exec"), {"__name__": "__doc_block__"})
        return
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef):
            assert hasattr(target, node.name), f"{block}: {target!r} has no '{node.name}'"
            documented = [a.arg for a in node.args.args + node.args.kwonlyargs]
            real = [p for p in inspect.signature(getattr(target, node.name)).parameters]
            assert documented == real, f"{block}: {node.name}{tuple(documented)} but the code has {tuple(real)}"


# ---- shell -------------------------------------------------------------------------------
def _commands(text: str) -> list[list[str]]:
    """Each simple command of a block: continuations joined, prompts, comments and heredoc
    bodies dropped, split on && || ; and |."""
    joined, heredoc = [], None
    for raw in text.replace("\\\n", " ").splitlines():
        if heredoc is not None:
            heredoc = None if raw.strip() == heredoc else heredoc
            continue
        line = re.sub(r"^\s*\$ ", "", raw)
        if m := re.search(r"<<-?\s*'?(\w+)'?", line):
            heredoc = m.group(1)
        joined.append(line)
    out = []
    for line in joined:
        try:
            words = shlex.split(line, comments=True)
        except ValueError:
            continue
        cmd: list[str] = []
        for w in words + [";"]:
            if w in ("&&", "||", ";", "|", "&"):
                if cmd:
                    out.append(cmd)
                cmd = []
            else:
                cmd.append(w)
    return out


def _strip_runner(cmd: list[str]) -> list[str]:
    """`.venv/bin/gma-ffc x` -> `gma-ffc x`; `python3 -m gma_ffc x` -> `gma-ffc x`."""
    if cmd and cmd[0].endswith("/gma-ffc"):
        return ["gma-ffc", *cmd[1:]]
    if len(cmd) > 2 and re.fullmatch(r"(.*/)?python3?", cmd[0]) and cmd[1:3] == ["-m", "gma_ffc"]:
        return ["gma-ffc", *cmd[3:]]
    return cmd


@functools.lru_cache(maxsize=None)
def _help_of(argv: tuple[str, ...]) -> str:
    run = subprocess.run([sys.executable, *argv, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"{' '.join(argv)} --help failed: {run.stderr.strip()[-300:]}"
    return run.stdout


def _check_command(cmd: list[str], where: Block) -> None:
    from gma_ffc.cli import build_parser

    cmd = _strip_runner(cmd)
    if cmd[0] == "gma-ffc":
        if any(re.search(r"[*\[\]|]|\.\.\.|^[A-Z][A-Z_.]+$|^[A-Z]+\.(yaml|csv)$", w) for w in cmd[1:]):
            # a usage line (REC..., CFG.yaml placeholders): the subcommand and flags must exist
            sub = cmd[1]
            helptext = build_parser()._subparsers._group_actions[0].choices[sub].format_help()  # type: ignore[union-attr]
            for flag in (w.split("=")[0] for w in cmd[2:] if w.startswith("--")):
                assert flag in helptext, f"{where}: 'gma-ffc {sub}' has no {flag}"
            return
        try:
            build_parser().parse_args(cmd[1:])
        except SystemExit as exc:
            raise AssertionError(f"{where}: `{shlex.join(cmd)}` is refused by the parser") from exc
        return
    if re.fullmatch(r"(.*/)?python3?", cmd[0]) and len(cmd) > 1:
        if cmd[1] == "-m":
            argv: tuple[str, ...] = ("-m", cmd[2])
            rest = cmd[3:]
            assert importlib.util.find_spec(cmd[2]) is not None, f"{where}: no module {cmd[2]}"
        elif cmd[1].startswith("scripts/") and cmd[1].endswith(".py"):
            assert (ROOT / cmd[1]).exists(), f"{where}: {cmd[1]} does not exist"
            argv, rest = (cmd[1],), cmd[2:]
        else:
            return
        flags = [w.split("=")[0] for w in rest if w.startswith("--")]
        if flags:
            helptext = _help_of(argv + tuple(w for w in rest[:1] if not w.startswith("-")))
            for flag in flags:
                assert flag in helptext, f"{where}: `{' '.join(argv)}` has no {flag}"
        return
    if cmd[0].startswith(("./scripts/", "scripts/")):
        path = ROOT / cmd[0].removeprefix("./")
        assert path.exists() and path.stat().st_mode & 0o111, f"{where}: {cmd[0]} is not an executable script"


@pytest.mark.parametrize("block", of("bash", "console"), ids=str)
def test_shell_blocks_name_commands_and_flags_that_exist(block: Block):
    for cmd in _commands(block.text):
        _check_command(cmd, block)


# ---- data formats ------------------------------------------------------------------------
@pytest.mark.parametrize("block", of("yaml", "json", "toml"), ids=str)
def test_data_blocks_parse(block: Block, tmp_path: Path):
    if block.lang == "json":
        json.loads(block.text)
    elif block.lang == "toml":
        tomllib.loads(block.text)
    else:
        doc = yaml.safe_load(block.text)
        _validate_if_config_fragment(doc, tmp_path)


def _validate_if_config_fragment(doc: object, tmp_path: Path) -> None:
    from gma_ffc.control.config import load_config

    base = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
    if not isinstance(doc, dict) or not set(doc) <= set(base) | {"learning", "monitor", "metrics"}:
        return
    merged = {**base, **doc, "model": str(ROOT / "config" / base["model"])}
    path = tmp_path / "cfg.yaml"
    path.write_text(yaml.safe_dump(merged))
    load_config(str(path))


# ---- figures -----------------------------------------------------------------------------
def test_the_readme_figures_are_the_ones_the_benchmarks_wrote():
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import figures
    finally:
        sys.path.remove(str(ROOT / "scripts"))
    text = (ROOT / "README.md").read_text()
    stale = figures.stale_blocks(text, figures.load())
    assert not stale, f"README.md blocks {stale} differ from docs/figures.json: run python scripts/figures.py"
    for key, fig in figures.load().items():
        script = re.search(r"scripts/[\w/]+\.(?:py|sh)", fig["command"])
        if fig["command"].startswith("gma-ffc "):         # a command of the tool itself: the parser knows it
            from gma_ffc.cli import build_parser
            build_parser().parse_args(shlex.split(fig["command"])[1:])
        else:
            assert script and (ROOT / script.group(0)).exists(), f"figure {key}: its command names no script that exists"
