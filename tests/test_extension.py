"""Extension points: a user's own method as ``module:function`` runs under every backend with
identical numbers; a malformed method output is refused before any file is written; method
specs, labels and registries behave as documented (docs/architecture.md)."""

from __future__ import annotations

import os
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core.registry import Imported, Registry, RegistryError, load_object
from qkf.transfer_alignment.benchmark import run_benchmark
from qkf.transfer_alignment.methods import (
    MethodOutputError,
    MethodSpecError,
    resolve_method,
    validate_output,
)
from qkf.transfer_alignment.methods.base import MethodOutput
from tests.conftest import cfg_with

runner = CliRunner()
SETS = ("scenario.duration_s=200", "run.chunk_trials=2")

USER_MODULE = '''
"""A user's own methods, outside the qkf package."""
import numpy as np
from qkf.transfer_alignment.methods.base import MethodOutput, new_filter


def run_half_kappa(cfg, data):
    """The fixed-Q KF with κ = 0.5, reporting its κ."""
    kf = new_filter(cfg, data)
    rec = kf.step_data(data, 0, data.n_epochs, kappa=0.5)
    kappa = np.full((data.n_trials, data.n_epochs), 0.5)
    return MethodOutput(est=rec.est, diverged=kf.diverged.copy(), kappa=kappa)


def run_bad_kappa(cfg, data):
    """Malformed: κ logged per period instead of per epoch."""
    out = run_half_kappa(cfg, data)
    out.kappa = out.kappa[:, ::10]
    return out


def run_not_an_output(cfg, data):
    return {"est": None}
'''


@pytest.fixture
def user_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """``mine_<id>``: a module in a folder of its own, importable here and in worker processes
    (through PYTHONPATH, as a user would arrange it)."""
    name = f"mine_{os.getpid()}_{tmp_path.name.replace('-', '_')}"
    folder = tmp_path / "userpkg"
    folder.mkdir()
    (folder / f"{name}.py").write_text(textwrap.dedent(USER_MODULE))
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")])
    )
    yield name
    sys.modules.pop(name, None)


def _rms(res) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
    return {m.name: m.rms for m in res.methods}


@pytest.mark.slow  # a process pool and a Ray cluster
def test_user_method_runs_identically_under_every_backend(
    user_module: str, tmp_path: Path, ray_cluster: Path
) -> None:
    # the session's Ray workers import the module from the cluster's folder
    written = tmp_path / "userpkg" / f"{user_module}.py"
    (ray_cluster / written.name).write_bytes(written.read_bytes())
    cfg = cfg_with(*SETS)
    spec = [f"half={user_module}:run_half_kappa", "kf"]
    inline = run_benchmark(cfg, spec, trials=5, seed=2, progress=False)
    assert [m.name for m in inline.methods] == ["half", "kf"]
    half = inline.methods[0]
    assert half.kappa is not None and np.all(half.kappa == 0.5)
    assert not np.array_equal(half.rms, inline.methods[1].rms)  # κ = 0.5 really was used
    pool = run_benchmark(cfg, spec, trials=5, seed=2, progress=False, workers=2)
    for name, rms in _rms(inline).items():
        np.testing.assert_array_equal(_rms(pool)[name], rms)
    remote = run_benchmark(cfg, spec, trials=5, seed=2, progress=False, backend="ray")
    for name, rms in _rms(inline).items():
        np.testing.assert_array_equal(_rms(remote)[name], rms)


@pytest.mark.parametrize(
    ("function", "message"),
    [
        ("run_bad_kappa", "kappa has shape (5, 20)"),
        ("run_not_an_output", "returned dict, not a MethodOutput"),
    ],
)
def test_malformed_output_is_refused_before_anything_is_written(
    user_module: str, tmp_path: Path, function: str, message: str
) -> None:
    out = tmp_path / "out"
    result = runner.invoke(
        app,
        [
            "bench",
            "paper",
            "--methods",
            f"kf,{user_module}:{function}",
            "--trials",
            "5",
            "--out",
            str(out),
            "--quiet",
            "--set",
            "scenario.duration_s=200",
        ],
    )
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert "Traceback" not in result.output
    assert not out.exists()


def test_validate_output_checks_every_field() -> None:
    good = MethodOutput(est=np.zeros((2, 3, 16)), diverged=np.zeros(2, bool))
    assert validate_output(good, "m", 2, 3) is good
    with pytest.raises(MethodOutputError, match="est has shape"):
        validate_output(good, "m", 2, 4)
    bad_div = MethodOutput(est=np.zeros((2, 3, 16)), diverged=np.zeros(2))
    with pytest.raises(MethodOutputError, match="diverged must be a boolean"):
        validate_output(bad_div, "m", 2, 3)
    neg = MethodOutput(est=np.zeros((2, 3, 16)), diverged=np.zeros(2, bool), kappa=-np.ones((2, 3)))
    with pytest.raises(MethodOutputError, match="finite and positive"):
        validate_output(neg, "m", 2, 3)


def test_method_specs() -> None:
    assert resolve_method("kf").name == "kf"
    assert resolve_method("nominal = kf").name == "nominal"
    fn = resolve_method("qkf.transfer_alignment.methods.fixed:run_kf")
    assert fn.method is resolve_method("kf").method
    with pytest.raises(MethodSpecError, match="unknown method 'nosuch'"):
        resolve_method("nosuch")
    with pytest.raises(MethodSpecError, match="cannot import"):
        resolve_method("no_such_module_xyz:run")
    with pytest.raises(MethodSpecError, match="no such model file"):
        resolve_method("policy:/nonexistent/model.zip")
    # one method named twice runs once; one label for two methods is refused
    once = run_benchmark(cfg_with(*SETS), ["kf", "kf"], trials=1, progress=False)
    assert [m.name for m in once.methods] == ["kf"]
    with pytest.raises(MethodSpecError, match="given twice"):
        run_benchmark(cfg_with(*SETS), ["a=kf", "a=imm"], trials=1, progress=False)


def test_registry() -> None:
    reg: Registry[int] = Registry("number")
    reg.register("one", 1)

    @reg.register("two")
    def _two() -> int:  # a decorator registers what it decorates
        return 2

    assert reg.names() == ["one", "two"] and "one" in reg and reg["one"] == 1
    with pytest.raises(RegistryError, match="unknown number 'three'; known: one, two"):
        reg["three"]
    with pytest.raises(RegistryError, match="registered twice"):
        reg.register("one", 11)
    assert load_object("numpy.linalg:norm") is np.linalg.norm
    with pytest.raises(RegistryError, match="has no attribute"):
        load_object("numpy:no_such_thing")


def test_an_imported_attribute_is_loaded_when_read() -> None:
    class Facts:
        norm = Imported("numpy.linalg:norm")
        missing = Imported("numpy:no_such_thing")  # refused when read, not when defined
        broken = Imported("no_such_package.module:NAME")

    assert Facts.norm is np.linalg.norm and Facts().norm is np.linalg.norm
    with pytest.raises(AttributeError, match="no_such_thing"):
        _ = Facts().missing
    with pytest.raises(ModuleNotFoundError, match="no_such_package"):  # its own error
        _ = Facts().broken
