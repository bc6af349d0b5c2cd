"""The README's Python examples run as written (on fewer trials and environments)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_readme_example_runs(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks, "README has no python example"
    monkeypatch.chdir(ROOT)
    for block in blocks:
        code = block.replace("trials=32", "trials=4").replace("num_envs=64", "num_envs=2")
        exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert out.count("CRLB") == 15
