"""Command-line help: typer renders help texts as rich markup, where ``[...]`` is a tag and
vanishes (``[default: 20]`` printed as nothing). No option or argument help may contain one."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _help_texts() -> list[tuple[str, int, str]]:
    out = []
    for folder in ("groundstation", "onboard", "sim"):
        for f in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(f.read_text())):
                if not isinstance(node, ast.Call):
                    continue
                name = getattr(node.func, "attr", getattr(node.func, "id", ""))
                if name not in ("Option", "Argument"):
                    continue
                for kw in node.keywords:
                    if kw.arg == "help" and isinstance(kw.value, ast.Constant):
                        out.append((str(f.relative_to(ROOT)), node.lineno, str(kw.value.value)))
    return out


def test_no_help_text_is_eaten_by_rich_markup() -> None:
    texts = _help_texts()
    assert len(texts) > 50  # the scan finds the CLI's options
    bad = [(f, line, text) for f, line, text in texts if "[" in text.replace("\\[", "")]
    assert bad == []
