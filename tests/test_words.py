"""Trust the words: every name a user can type is in the words that tell them about it.

The registries are the truth: the methods (:data:`qkf.transfer_alignment.methods.METHODS`, with
``BUILTIN_METHODS`` for ``--methods all``, and the ``FACTORY:ARGUMENT`` factories of
``METHOD_FACTORIES``), the Gymnasium ids under ``qkf/`` (registered by ``import envs``, also
listed in ``envs.ENVIRONMENTS``), the rewards (``envs.REWARDS`` and those of each environment),
the agent algorithms (``agents.algorithms.ALGORITHMS``) and the presets of
``configs/<problem>/``. These tests fail when a registered name is missing from the README, the
docs or ``qkf bench --help``, or when the words name something that is not registered (or a
file that does not exist), so a name cannot be added, renamed or removed without the words
following it.

Only the project's own names are checked: an installed plugin's method or reward (entry points of
another distribution) need not be in this project's README.
"""

from __future__ import annotations

import fnmatch
import functools
import json
import re
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import pytest

from qkf.core.presets import preset_names
from qkf.core.registry import Registry

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
PROJECT_MODULES = ("qkf", "envs", "agents")
"""Top-level packages of this project: an entry point into any of them is the project's own."""


# --- helpers --------------------------------------------------------------------------------


def _read(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def _own_names(registry: Registry[Any]) -> list[str]:
    """The registry's names, less those installed by another distribution's entry points."""
    foreign: set[str] = set()
    if registry.group is not None:
        for ep in entry_points(group=registry.group):
            if ep.value.split(":")[0].split(".")[0] not in PROJECT_MODULES:
                foreign.add(ep.name)
    return [name for name in registry.names() if name not in foreign]


@functools.cache
def _registered() -> dict[str, list[str]]:
    """The project's own registered names, read in a fresh interpreter: other tests of this
    process register examples of their own (the docs' recipes add rewards and methods), which
    must not count as the project's."""
    code = """
import json
import envs
from agents.algorithms import ALGORITHMS
from qkf.transfer_alignment.methods import BUILTIN_METHODS, METHOD_FACTORIES, METHODS
from tests.test_words import _own_names
envs_ = envs.ENVIRONMENTS
rewards = {n for e in _own_names(envs_) for n in _own_names(envs_[e].rewards)}
print(json.dumps({
    "methods": _own_names(METHODS),
    "builtin": list(BUILTIN_METHODS),
    "factories": _own_names(METHOD_FACTORIES),
    "rewards": sorted(rewards | set(_own_names(envs.REWARDS))),
    "algorithms": _own_names(ALGORITHMS),
}))
"""
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    names: dict[str, list[str]] = json.loads(res.stdout.strip().splitlines()[-1])
    return names


def _section(text: str, heading: str) -> str:
    """The part of a Markdown text under ``heading`` (a whole heading line, ``#`` included), up
    to the next heading of the same or a higher level; fails the test if there is none."""
    level = len(heading) - len(heading.lstrip("#"))
    lines = text.splitlines()
    try:
        start = lines.index(heading)
    except ValueError:
        pytest.fail(f"no heading {heading!r}", pytrace=False)
    end = len(lines)
    in_code = False
    for i in range(start + 1, len(lines)):
        if lines[i].startswith("```"):  # a '# comment' inside a code block is no heading
            in_code = not in_code
        m = re.match(r"(#+) ", lines[i])
        if not in_code and m and len(m.group(1)) <= level:
            end = i
            break
    return "\n".join(lines[start + 1 : end])


def _table_rows(text: str) -> list[list[str]]:
    """The body rows of the Markdown tables in ``text``, as cells.

    A table is a run of ``|`` lines whose second line is the rule under the header; a run
    without one (say rows cut off from their table by a blank line) is no table when rendered,
    so its rows are not returned.
    """
    rows: list[list[str]] = []
    block: list[list[str]] = []
    for line in [*text.splitlines(), ""]:
        if line.startswith("|"):
            block.append([cell.strip() for cell in line.strip().strip("|").split("|")])
            continue
        if len(block) >= 2 and all(re.fullmatch(r":?-+:?", cell) for cell in block[1]):
            rows.extend(block[2:])
        block = []
    return rows


def _quoted(text: str) -> list[str]:
    """The ``code spans`` of a Markdown text."""
    return re.findall(r"`([^`\n]+)`", text)


def _docs_text() -> str:
    return "\n".join(_read(p) for p in sorted(DOCS.glob("*.md")))


def _missing(names: list[str], where: str) -> list[str]:
    return [name for name in names if name not in where]


# --- methods ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def methods() -> tuple[list[str], list[str], list[str]]:
    """(every method name, those ``all`` runs, the factories), the project's own."""

    reg = _registered()
    return reg["methods"], reg["builtin"], reg["factories"]


def test_readme_methods_table_is_the_registry(
    methods: tuple[list[str], list[str], list[str]],
) -> None:
    names, builtin, factories = methods
    section = _section(_read(README), "### Methods (`--methods`, default all)")
    rows = _table_rows(section)
    listed = [_quoted(row[0])[0] for row in rows]
    assert sorted(listed) == sorted(names), (
        f"README Methods table: missing {sorted(set(names) - set(listed))}, "
        f"not registered {sorted(set(listed) - set(names))}"
    )
    # the table marks exactly the methods `all` leaves out
    named_only = [_quoted(row[0])[0] for row in rows if "not in `all`" in row[0]]
    assert sorted(named_only) == sorted(set(names) - set(builtin))
    # and says how to reach every factory (policy:PATH)
    assert _missing([f"`{f}:" for f in factories], section) == []


def test_methods_doc_names_and_describes_every_method(
    methods: tuple[list[str], list[str], list[str]],
) -> None:
    names, builtin, factories = methods
    text = _read(DOCS / "methods.md")
    # the list of names under "Common ground": `all` runs exactly the built-ins, in order
    bullet = re.search(
        r"^- a built-in name \((.*?); `all` runs these\)(.*?)\n- ", text, re.S | re.M
    )
    assert bullet, "docs/methods.md: no '- a built-in name (…; `all` runs these)…' bullet"
    assert _quoted(bullet.group(1)) == builtin
    named_only = _quoted(bullet.group(2))
    assert sorted(n for n in named_only if n in names) == sorted(set(names) - set(builtin)), (
        "docs/methods.md names the methods `all` leaves out after the built-in list"
    )
    # every method and factory has a section of its own: "## Title (`name`)"
    headings = re.findall(r"^## .*\(`([^`]+)`\)$", text, flags=re.M)
    # the variants tuned on the training mixture share one section, which names each of them
    mixed = _section(text, "## Tuned on the training mixture (`…-mixed`)")
    covered = {n for n in names if n.endswith("-mixed") and f"`{n}`" in mixed}
    assert sorted(set(names) - set(headings) - covered) == [], (
        "docs/methods.md: methods without a section"
    )
    assert [f for f in factories if not any(h.startswith(f"{f}:") for h in headings)] == []


def test_methods_doc_config_keys_cover_every_setting() -> None:
    """The "Config keys" table lists every setting a registered method declares."""
    from qkf.transfer_alignment.methods import METHODS, declared_settings

    rows = _table_rows(_section(_read(DOCS / "methods.md"), "## Config keys"))
    documented: set[str] = set()
    for row in rows:
        spans = _quoted(row[0])  # `adaptive.qkf.alpha` / `gamma`: gamma is adaptive.qkf.gamma
        if not spans:
            continue
        prefix = spans[0].rpartition(".")[0]
        documented.update([spans[0], *(f"{prefix}.{s}" for s in spans[1:])])
    declared: set[str] = set()
    for name in _registered()["methods"]:
        settings = declared_settings(METHODS[name])
        if settings is not None:
            section, model = settings
            declared.update(f"adaptive.{section}.{field}" for field in model.model_fields)
    assert sorted(declared - documented) == []


def test_bench_help_names_every_method(methods: tuple[list[str], list[str], list[str]]) -> None:
    """``qkf bench --help`` names every method; its ``all`` list is ``BUILTIN_METHODS``.

    The help is a literal (importing the registry when the CLI starts would load numba and the
    filter: about 0.5 s more for every ``qkf`` command), so this test is what keeps it true.
    """
    import typer
    from typer.testing import CliRunner

    from qkf.cli import app

    names, builtin, factories = methods
    # the option's own text: "'all' (default): a, b, …; named only: c (…), d (…); f:…"
    bench = typer.main.get_command(app).commands["bench"]  # type: ignore[attr-defined]
    option = next(p for p in bench.params if "--methods" in p.opts)
    words = " ".join(option.help.split())
    match = re.search(r"'all' \(default\): (.*?); named only: (.*?); ", words)
    assert match, f"--methods help: no \"'all' (default): …; named only: …;\" in {words!r}"
    assert [w.strip() for w in match.group(1).split(",")] == builtin
    only = [w.strip() for w in re.sub(r"\([^)]*\)", "", match.group(2)).split(",")]
    assert sorted(only) == sorted(set(names) - set(builtin))
    # and the rendered help, as a user sees it (wide, so that no name is wrapped)
    result = CliRunner().invoke(
        app, ["bench", "--help"], env={"COLUMNS": "400", "NO_COLOR": "1", "TERM": "dumb"}
    )
    assert result.exit_code == 0, result.output
    shown = " ".join(re.sub(r"[│╭╮╰╯─]", " ", result.output).split())
    assert _missing([*names, *(f"{f}:" for f in factories)], shown) == []


# --- environments, rewards, agents -----------------------------------------------------------


def test_every_environment_id_is_documented() -> None:
    import gymnasium as gym

    import envs

    ids = sorted({k for k in gym.registry if k.startswith("qkf/")} | set(envs.ENVIRONMENTS))
    assert ids, "import envs registered no qkf/ id"
    missing = {
        name: _missing(ids, _read(path))
        for name, path in (("docs/environment.md", DOCS / "environment.md"), ("README", README))
    }
    assert missing == {"docs/environment.md": [], "README": []}


def test_every_reward_is_in_the_environment_doc() -> None:
    """Every reward of every environment (``envs.ENVIRONMENTS[id].rewards``; for the transfer
    alignment ``envs.REWARDS``) is a row of a table under "Rewards" in docs/environment.md."""

    rewards = set(_registered()["rewards"])
    section = _section(_read(DOCS / "environment.md"), "## Rewards")
    listed = {_quoted(row[0])[0] for row in _table_rows(section) if _quoted(row[0])}
    assert sorted(rewards - listed) == []


def test_every_algorithm_is_documented() -> None:

    words = _read(README) + _docs_text()
    quoted = set(_quoted(words))
    assert [a for a in _registered()["algorithms"] if a not in quoted] == []


# --- presets, paths and modules ---------------------------------------------------------------

README_PRESET_FOLDERS = ("transfer_alignment", "redundant_gyros", "sca_fusion", "alignment")
"""The problems whose scenario presets the README's Presets table lists one by one (the training
configs are one row, ``training/train_*.yaml``; docs/environment.md has their table)."""


def test_readme_preset_tables_list_every_preset() -> None:
    text = _read(README)
    presets = _section(text, "### Presets (`configs/<problem>/`)")
    patterns = [s for row in _table_rows(presets) for s in _quoted(row[0])]
    missing = [
        f"{folder}/{name}.yaml"
        for folder in (*README_PRESET_FOLDERS, "training")
        for name in preset_names(folder)
        if not any(fnmatch.fnmatch(f"{folder}/{name}.yaml", p) for p in patterns)
    ]
    assert missing == []
    stale = [p for p in patterns if not any((ROOT / "configs").glob(p))]
    assert stale == []

    studies = _section(text, "### Studies (`configs/transfer_alignment/studies/`)")
    listed = {_quoted(row[0])[0] for row in _table_rows(studies)}
    expected = {f"{name}.yaml" for name in preset_names("transfer_alignment/studies")}
    assert sorted(expected ^ listed) == []


def test_models_doc_lists_every_transfer_alignment_preset() -> None:
    text = _read(DOCS / "models.md")
    table = text.split("**Presets** (`configs/transfer_alignment/*.yaml`", 1)
    assert len(table) == 2, "docs/models.md: no Presets table for configs/transfer_alignment/"
    listed = {_quoted(row[0])[0] for row in _table_rows(table[1].split("\n\n**", 1)[0])}
    assert sorted(set(preset_names("transfer_alignment")) ^ listed) == []


FICTIONAL_PATHS = {"configs/mine.yaml"}
"""Paths the words use as examples of a user's own file (the README's error message)."""


@pytest.mark.parametrize("doc", ["README.md", *sorted(f"docs/{p.name}" for p in DOCS.glob("*.md"))])
def test_cited_config_paths_exist(doc: str) -> None:
    """Every ``configs/…`` path (or glob) the words cite names something in the checkout."""
    cited = {
        path.rstrip(".") for path in re.findall(r"(?<![\w/])configs/[\w./*-]*", _read(ROOT / doc))
    }
    stale = sorted(path for path in cited - FICTIONAL_PATHS if not _names_something(path))
    assert stale == []


def _names_something(path: str) -> bool:
    """A path of the checkout that exists, or a glob that matches something."""
    if "*" in path:
        return any(ROOT.glob(path.rstrip("/")))
    return (ROOT / path).exists()


def test_readme_module_table_names_modules_that_exist() -> None:
    """The modules of the README's Python API table exist (``.name`` is relative to the row's
    first module's package)."""
    rows = _table_rows(_section(_read(README), "## Python API"))
    missing = []
    for row in rows:
        package = ""
        for span in _quoted(row[0]):
            name = package + span if span.startswith(".") else span
            package = name.rpartition(".")[0] if not span.startswith(".") else package
            path = ROOT.joinpath(*name.strip(".").split("."))
            if not (path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()):
                missing.append(name)
    assert rows and missing == []
