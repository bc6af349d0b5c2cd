"""The documentation: its examples run as written, and the project cites its own docs/, not an
outside specification."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), flags=re.S)


def test_architecture_examples_run(capsys: pytest.CaptureFixture[str]) -> None:
    blocks = _python_blocks(ROOT / "docs" / "architecture.md")
    assert len(blocks) >= 2
    for block in blocks:
        exec(compile(block, "docs/architecture.md", "exec"), {"__name__": "docs_example"})
    out = capsys.readouterr().out
    assert re.search(r"^kf [\d.]+ ppm$", out, flags=re.M)
    assert re.search(r"^boost [\d.]+ ppm$", out, flags=re.M)
    assert re.search(r"^reward -[\d.e+-]+$", out, flags=re.M)


def test_code_cites_docs_not_an_outside_spec() -> None:
    sources = [
        p
        for top in ("qkf", "envs", "agents", "benchmarks", "configs", "docs")
        for p in (ROOT / top).rglob("*")
        if p.suffix in (".py", ".md", ".yaml")
    ]
    sources.append(ROOT / "README.md")
    offenders = [
        str(p.relative_to(ROOT))
        for p in sources
        if re.search(r"SPEC(\.md| ?§)|shared/", p.read_text())
    ]
    assert offenders == []


def test_docs_cited_by_the_code_exist() -> None:
    cited = set()
    for top in ("qkf", "envs", "agents"):
        for p in (ROOT / top).rglob("*.py"):
            cited.update(re.findall(r"docs/([\w-]+\.md)", p.read_text()))
    assert cited, "the code cites no documentation"
    missing = sorted(c for c in cited if not (ROOT / "docs" / c).is_file())
    assert missing == []
