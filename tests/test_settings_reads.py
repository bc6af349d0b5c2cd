"""Every read of a method's settings section is declared (issue 36: "a method owns its
settings"; docs/architecture.md, "Recipe: add a method").

A method declares the section of ``adaptive`` it owns and the other methods' sections it reads
with :func:`~qkf.transfer_alignment.methods.base.uses_settings` (``reads=``); code that is not
a method reads a method's settings through it (:func:`.base.settings_of`). This test reads the
source of ``qkf``, ``envs`` and ``agents`` and refuses any ``<x>.adaptive.<section>`` that no
declaration covers: inside a declared method (a decorated function or class) its own
declaration, elsewhere in a module the declarations of the methods that module defines.
``adaptive.actions``, the κ action set every method shares, is nobody's section.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from qkf.core.config import StrictModel
from qkf.transfer_alignment.adaptive import AdaptiveConfig, ClockConfig, TunedConfig
from qkf.transfer_alignment.methods import METHODS
from qkf.transfer_alignment.methods.base import (
    declared_sections,
    declared_settings,
    settings_of,
    uses_settings,
)
from tests.conftest import ROOT, cfg_with

PACKAGES = ("qkf", "envs", "agents")
SCHEMA = Path("qkf/transfer_alignment/config.py")  # where the sections are defined
SHARED = {"actions"}
SECTIONS = set(AdaptiveConfig.model_fields) - SHARED


def _module_name(path: Path) -> str:
    return ".".join(path.with_suffix("").parts).removesuffix(".__init__")


def _reads(tree: ast.Module) -> list[tuple[str | None, str, int]]:
    """``(top-level name, section, line)`` of every ``<x>.adaptive.<section>`` in a module;
    the name is the top-level function or class the read sits in (None at module level)."""
    found: list[tuple[str | None, str, int]] = []
    for top in tree.body:
        owner = top.name if isinstance(top, ast.FunctionDef | ast.ClassDef) else None
        for node in ast.walk(top):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Attribute)
                and node.value.attr == "adaptive"
                and node.attr in SECTIONS
            ):
                found.append((owner, node.attr, node.lineno))
    return found


def _declarations(module: object) -> dict[str, tuple[str, ...]]:
    """The declared sections of every method a module defines, by its top-level name."""
    out: dict[str, tuple[str, ...]] = {}
    for name, obj in vars(module).items():
        home = getattr(obj, "__module__", None) or type(obj).__module__
        if home == getattr(module, "__name__", None) and declared_settings(obj) is not None:
            out[name] = declared_sections(obj)
    return out


def test_every_settings_read_is_declared() -> None:
    undeclared: list[str] = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT)
            if rel == SCHEMA:
                continue
            reads = _reads(ast.parse(path.read_text(encoding="utf-8")))
            if not reads:
                continue
            declared = _declarations(importlib.import_module(_module_name(rel)))
            in_module = {s for sections in declared.values() for s in sections}
            for owner, section, line in reads:
                allowed = set(declared[owner]) if owner in declared else in_module
                if section not in allowed:
                    undeclared.append(f"{rel}:{line}: adaptive.{section} in {owner}")
    assert not undeclared, "reads no declaration covers:\n" + "\n".join(undeclared)


def test_the_scan_finds_an_undeclared_read() -> None:
    """The scan above can fail: a module whose method reads a section it does not declare."""
    source = "def run(cfg, data):\n    return cfg.adaptive.clock.block_s\n"
    reads = _reads(ast.parse(source))
    assert reads == [("run", "clock", 2)]


def test_methods_are_declared_one_way() -> None:
    """No class declares its settings by assigning the attributes: the decorator is the way,
    for functions and classes alike."""
    assigned: list[str] = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef):
                    for stmt in node.body:
                        targets = stmt.targets if isinstance(stmt, ast.Assign) else []
                        for t in targets:
                            if isinstance(t, ast.Name) and t.id == "settings_section":
                                assigned.append(f"{path.relative_to(ROOT)}:{stmt.lineno}")
    assert not assigned, assigned


def test_the_builtin_methods_declare_what_they_read() -> None:
    assert declared_sections(METHODS["clock"]) == ("clock", "tuned")
    assert declared_sections(METHODS["kf-tuned"]) == ("tuned",)
    assert declared_sections(METHODS["kf"]) == ()
    # a -mixed variant declares what its base declares
    assert declared_sections(METHODS["clock-mixed"]) == declared_sections(METHODS["clock"])


def test_reads_name_builtin_sections_only() -> None:
    class Mine(StrictModel):
        gain: float = 1.0

    with pytest.raises(ValueError, match="not a built-in section"):
        uses_settings("mine", Mine, reads=("no_such_section",))


def test_settings_of_reads_through_the_declaration() -> None:
    cfg = cfg_with("adaptive.clock.block_s=25", "adaptive.tuned.trials=3")
    assert settings_of(METHODS["clock"], cfg, ClockConfig).block_s == 25.0
    assert settings_of(METHODS["kf-tuned"], cfg, TunedConfig).trials == 3
    with pytest.raises(ValueError, match="does not declare settings of type TunedConfig"):
        settings_of(METHODS["clock"], cfg, TunedConfig)
    with pytest.raises(ValueError, match="does not declare"):
        settings_of(METHODS["kf"], cfg, TunedConfig)
