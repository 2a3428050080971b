"""The Python snippets of docs/python.md and python/README.md run as written."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PAGES = [REPO / "docs" / "python.md", REPO / "python" / "README.md"]


def snippets() -> list[tuple[str, int, str]]:
    found = []
    for page in PAGES:
        text = page.read_text()
        for match in re.finditer(r"```python\n(.*?)```", text, re.S):
            line = text[: match.start()].count("\n") + 1
            found.append((page.name, line, match.group(1)))
    return found


@pytest.mark.parametrize("page, line, code", snippets(), ids=lambda v: str(v)[:20])
def test_a_snippet_runs_as_written(page, line, code, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(code, f"{page}:{line}", "exec"), {"__name__": "__snippet__"})


def test_every_page_has_snippets():
    assert {page for page, _, _ in snippets()} == {p.name for p in PAGES}
