"""Packaging and layering: the wheel builds without warnings and carries exactly the files of the
tree; an installed wheel finds the presets by name; the package list in pyproject.toml matches
the tree; qkf never imports envs or agents; torch is loaded only by the commands that need it;
``python -m qkf`` works."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _packages_in_tree() -> set[str]:
    found = set()
    for top in ("qkf", "envs", "agents"):
        for init in (ROOT / top).rglob("__init__.py"):
            found.add(".".join(init.parent.relative_to(ROOT).parts))
    return found


def test_pyproject_lists_every_package() -> None:
    listed = set(
        tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    presets = {p for p in listed if p == "qkf.presets" or p.startswith("qkf.presets.")}
    assert _packages_in_tree() == listed - presets
    # every preset folder of configs/ is listed (the wheel carries exactly the source presets)
    folders = {p.parent for p in (ROOT / "configs").rglob("*.yaml")}
    mapped = {".".join(("qkf", "presets", *f.relative_to(ROOT / "configs").parts)) for f in folders}
    assert mapped == presets - {"qkf.presets"}


def _modules(path: Path) -> set[str]:
    """Every module a file imports, anywhere in it (lazy imports inside functions included),
    as dotted names (``from a.b import c`` gives ``a.b`` and ``a.b.c``)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return names


def _imports(path: Path) -> set[str]:
    return {m.split(".")[0] for m in _modules(path)}


PROBLEMS = ("transfer_alignment", "redundant_gyros", "sca_fusion", "alignment")
TOP_CLI = ROOT / "qkf" / "cli.py"


def test_the_library_never_imports_its_consumers() -> None:
    """qkf/ imports neither envs nor agents, envs never imports agents; only the top-level
    command line (qkf/cli.py) sits above all three (no other exemption)."""
    offenders = [
        str(p.relative_to(ROOT))
        for p in (ROOT / "qkf").rglob("*.py")
        if p != TOP_CLI and _imports(p) & {"envs", "agents"}
    ]
    assert offenders == []
    assert not [p for p in (ROOT / "envs").rglob("*.py") if "agents" in _imports(p)]


def test_no_problem_package_imports_another_and_the_core_none() -> None:
    offenders = []
    for folder in ("core", *PROBLEMS):
        for path in (ROOT / "qkf" / folder).rglob("*.py"):
            others = {
                m
                for m in _modules(path)
                if m.startswith("qkf.")
                and len(m.split(".")) > 1
                and m.split(".")[1] in PROBLEMS
                and m.split(".")[1] != folder
            }
            if others:
                offenders.append(f"{path.relative_to(ROOT)}: {sorted(others)}")
    assert offenders == []


def test_agents_reach_the_problems_through_the_registries() -> None:
    """No module of agents/ imports a problem package: the agents reach a problem through
    qkf.core.problem.PROBLEMS (its bench and families study included), the method registries
    and the environment registry (policy_runner)."""
    direct = {
        str(p.relative_to(ROOT))
        for p in (ROOT / "agents").rglob("*.py")
        if any(m.startswith("qkf.") and m.split(".")[1] in PROBLEMS for m in _modules(p))
    }
    assert direct == set()


def test_only_the_top_level_command_line_mounts_the_apps() -> None:
    """Each problem's cli.py (and agents/cli.py) exports a Typer app; only qkf/cli.py imports
    them."""
    apps = {f"qkf.{p}.cli" for p in PROBLEMS} | {"agents.cli"}
    for name in apps:
        path = ROOT / Path(*name.split(".")).with_suffix(".py")
        assert "app = typer.Typer(" in path.read_text(), name
    users = [
        str(p.relative_to(ROOT))
        for top in ("qkf", "envs", "agents")
        for p in (ROOT / top).rglob("*.py")
        if p != TOP_CLI and _modules(p) & apps
    ]
    assert users == []
    assert apps <= _modules(TOP_CLI)


def _run(code: str, cwd: Path, env: dict[str, str] | None = None) -> str:
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert res.returncode == 0, res.stderr[-3000:]
    return res.stdout


def test_torch_is_loaded_only_by_agent_commands(tmp_path: Path) -> None:
    code = f"""
import sys
from typer.testing import CliRunner
import envs, gymnasium as gym
from qkf.cli import app
r = CliRunner().invoke(app, ["crlb", "paper", "--set", "scenario.duration_s=20",
                             "--out", r"{tmp_path / "c.csv"}"])
assert r.exit_code == 0, r.output
gym.make("qkf/TransferAlignment-v0", overrides=["scenario.duration_s=20"]).reset(seed=0)
print("torch" in sys.modules)
"""
    assert _run(code, ROOT).strip() == "False"


def test_python_dash_m_qkf(tmp_path: Path) -> None:
    res = subprocess.run(
        [sys.executable, "-m", "qkf", "--help"], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0 and "bench" in res.stdout


# What a wheel is built from (setuptools reads nothing else with an explicit package list), and
# where each source folder lands in the wheel: configs/ becomes qkf/presets/.
WHEEL_SOURCES = {"qkf": "qkf", "envs": "envs", "agents": "agents", "configs": "qkf/presets"}
# setuptools' warning for a data folder that is no listed package, one 40-line block per folder
# (about 1,000 lines for the zoo's seed_N/ and evaluation/ folders): a newcomer reads it as failure
BUILD_WARNINGS = ("would be ignored", "absent from the `packages`")


def _tree_files() -> set[str]:
    """Every file the wheel must carry, as its path in the wheel (caches and hidden files, an
    editor's or numba's, left out)."""
    found = set()
    for src, dest in WHEEL_SOURCES.items():
        for p in (ROOT / src).rglob("*"):
            rel = p.relative_to(ROOT / src)
            if p.is_file() and not any(s == "__pycache__" or s.startswith(".") for s in rel.parts):
                found.add(f"{dest}/{rel.as_posix()}")
    return found


def _build_source(to: Path) -> Path:
    """A copy of what the build reads: built in place, the checkout would get build/ and
    *.egg-info, and a stale build/lib (a module removed since) would end up in the wheel."""
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, to / name)
    for src in WHEEL_SOURCES:
        shutil.copytree(ROOT / src, to / src, ignore=shutil.ignore_patterns("__pycache__", ".*"))
    return to


@pytest.mark.slow
def test_installed_wheel_finds_presets_by_name(tmp_path: Path) -> None:
    """Build the wheel (quietly, every file of the tree in it), install it alone into a folder,
    and use it from elsewhere."""
    dist = tmp_path / "dist"
    source = tmp_path / "source"
    source.mkdir()
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(dist),
            str(_build_source(source)),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert build.returncode == 0, build.stderr[-3000:]
    log = build.stdout + build.stderr
    assert "deprecat" not in log.lower()
    warned = [w for w in BUILD_WARNINGS if w in log]
    assert not warned, f"the build warns ({warned}):\n{log[:3000]}"
    (wheel,) = dist.glob("qkf-*.whl")
    with zipfile.ZipFile(wheel) as z:
        carried = {n for n in z.namelist() if ".dist-info/" not in n}
    tree = _tree_files()
    assert carried == tree, (
        f"in the tree, not in the wheel: {sorted(tree - carried)[:10]}; "
        f"in the wheel, not in the tree: {sorted(carried - tree)[:10]}"
    )
    site = tmp_path / "site"
    inst = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--target", str(site), str(wheel)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert inst.returncode == 0, inst.stderr[-3000:]
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}
    code = f"""
import qkf, gymnasium as gym, envs
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.study import load_study
assert qkf.__file__.startswith({str(site)!r}), qkf.__file__
assert load_config("thermal_snap").name == "thermal-snap"
assert load_config("thermal-snap").name == "thermal-snap"
study, cases = load_study("matching")
assert len(cases) == 2
env = gym.make("qkf/TransferAlignment-v0", scenario="thermal_snap",
               overrides=["scenario.duration_s=20"])
env.reset(seed=1)
print("ok")
"""
    assert _run(code, work, env).strip() == "ok"
