"""numba's cache files are discarded when, and only when, a module with compiled code changed
(qkf.core.numba_cache)."""

from __future__ import annotations

import os
from pathlib import Path

import qkf
from qkf.core.numba_cache import STAMP_NAME, compiled_sources_digest, discard_stale_caches


def _tree(root: Path) -> dict[str, Path]:
    """A package with a compiled module, a plain one, numba caches, and a bytecode file."""
    (root / "sub" / "__pycache__").mkdir(parents=True)
    (root / "__pycache__").mkdir()
    (root / "kernel.py").write_text("@nb.njit(cache=True)\ndef f(x):\n    return x\n")
    (root / "sub" / "helpers.py").write_text("@kernel_jit()\ndef g(x):\n    return x\n")
    (root / "plain.py").write_text("X = 1\n")
    return {
        "index": root / "__pycache__" / "kernel.f-1.py311.nbi",
        "code": root / "__pycache__" / "kernel.f-1.py311.1.nbc",
        "nested": root / "sub" / "__pycache__" / "helpers.g-1.py311.nbi",
        "bytecode": root / "__pycache__" / "kernel.cpython-311.pyc",
    }


def _write(files: dict[str, Path]) -> None:
    for path in files.values():
        path.write_bytes(b"cache")


def test_caches_go_when_compiled_code_changes_and_stay_otherwise(tmp_path: Path) -> None:
    files = _tree(tmp_path)
    _write(files)
    # no stamp yet: whatever is cached was written under an unknown fingerprint
    assert discard_stale_caches(tmp_path)
    assert not any(files[k].exists() for k in ("index", "code", "nested"))
    assert files["bytecode"].exists()  # not numba's
    stamp = tmp_path / "__pycache__" / STAMP_NAME
    assert stamp.read_text() == compiled_sources_digest(tmp_path)

    _write(files)
    assert not discard_stale_caches(tmp_path)  # nothing changed
    (tmp_path / "plain.py").write_text("X = 2\n")  # no compiled code in it
    assert not discard_stale_caches(tmp_path)
    assert all(path.exists() for path in files.values())

    # a change to one compiled module discards the caches of all, nested folders included
    (tmp_path / "sub" / "helpers.py").write_text("@kernel_jit()\ndef g(x):\n    return x + 1\n")
    assert discard_stale_caches(tmp_path)
    assert not any(files[k].exists() for k in ("index", "code", "nested"))
    assert stamp.read_text() == compiled_sources_digest(tmp_path)


def test_the_package_import_leaves_a_current_stamp() -> None:
    root = Path(qkf.__file__).resolve().parent
    stamp = root / "__pycache__" / STAMP_NAME
    if os.access(root, os.W_OK):  # a read-only install keeps numba's caches elsewhere
        assert stamp.read_text() == compiled_sources_digest(root)
