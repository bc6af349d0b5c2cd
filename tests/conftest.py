from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from qkf.core.plotting import PLACEHOLDER_ENV, placeholder_png
from qkf.transfer_alignment.config import Config, load_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs" / "transfer_alignment"
TRAINING = ROOT / "configs" / "training"
GYRO_CONFIGS = ROOT / "configs" / "redundant_gyros"
FUSION_CONFIGS = ROOT / "configs" / "sca_fusion"
ALIGNMENT_CONFIGS = ROOT / "configs" / "alignment"


@pytest.fixture
def bare_gyro_policy(tmp_path: Path) -> str:
    """An untrained PPO of the v3 gyro environment (its random weights, made large, still choose
    κ from the observation), saved bare: ``PATH@ENV_ID`` (``policy:`` prefixes a method spec).
    Its episodes are shortened to 160 s (judged from 100 s)."""
    import torch
    from stable_baselines3 import PPO

    from envs.redundant_gyros.sb3 import BatchedGyroSB3Env

    env = BatchedGyroSB3Env(
        2, "gyro_noise_levels", observation="v3", overrides=["scenario.duration_s=160"]
    )
    model = PPO("MlpPolicy", env, n_steps=8, batch_size=16, seed=3, device="cpu")
    first: Any = model.policy.mlp_extractor.policy_net[0]
    with torch.no_grad():  # large weights: the greedy κ follows the observation
        first.weight.mul_(30.0)
        model.policy.action_net.weight.mul_(30.0)
    path = tmp_path / "gyro_ppo.zip"
    model.save(path)
    return f"{path}@qkf/RedundantGyroCalibration-v3"


@pytest.fixture
def paper() -> Config:
    return load_config(CONFIGS / "paper.yaml")


def cfg_with(*sets: str, base: str = "paper.yaml") -> Config:
    """A preset with ``--set`` style overrides."""
    return load_config(CONFIGS / base, list(sets))


def align_quat_sign(q: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Flip quaternions (last axis 4) onto the hemisphere of ``ref`` (q and −q are one rotation)."""
    s = np.sign(np.sum(q * ref, axis=-1, keepdims=True))
    return q * np.where(s == 0, 1.0, s)


def _tracked_files() -> list[Path]:
    import subprocess

    try:
        listed = subprocess.run(
            ["git", "-C", str(ROOT), "ls-files", "-z"], capture_output=True, check=True
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return []
    return [ROOT / p for p in listed.decode().split("\0") if p]


@pytest.fixture(scope="session", autouse=True)
def _no_command_deletes_a_file_it_did_not_write() -> Iterator[None]:
    """The whole suite fails if anything it ran deleted a file of the checkout, rewrote a
    shipped zoo file, or removed a file of the user's in the project root (issue 18)."""
    tracked = [p for p in _tracked_files() if p.exists()]
    zoo = {p: p.stat().st_mtime_ns for p in tracked if "agents/zoo/" in p.as_posix()}
    sentinel = ROOT / f".qkf-test-sentinel-{os.getpid()}"
    sentinel.write_text("a file of the user's: no test may remove it\n")
    yield
    try:
        gone = [str(p.relative_to(ROOT)) for p in tracked if not p.exists()]
        touched = [str(p.relative_to(ROOT)) for p, t in zoo.items()
                   if p.exists() and p.stat().st_mtime_ns != t]  # fmt: skip
        if not sentinel.exists():
            gone.append(sentinel.name)
        if gone or touched:
            pytest.fail(f"the suite deleted {gone} and rewrote {touched}", pytrace=False)
    finally:
        sentinel.unlink(missing_ok=True)


@pytest.fixture(scope="session", autouse=True)
def _tuning_cache_of_the_session(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Tuned methods cache their results under ``$QKF_CACHE_DIR``: the suite's own cache, so
    that no test reads a user's cached tuning or writes into their home; the results cache is
    off, and SB3's default log folder is the session's (nothing left in ``/tmp``)."""
    before = os.environ.get("QKF_CACHE_DIR")
    os.environ["QKF_CACHE_DIR"] = str(tmp_path_factory.mktemp("qkf_cache"))
    # and no results cache: a test that compares two runs must see both computed
    # (tests/test_results_cache.py turns it on where it is the subject)
    os.environ["QKF_NO_CACHE"] = "1"
    # SB3 agents that learn without a TensorBoard folder make an empty /tmp/SB3-<time>/ each
    # unless SB3_LOGDIR names one: the session's own
    sb3_before = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3_logs"))
    yield
    os.environ.pop("QKF_NO_CACHE", None)
    if sb3_before is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = sb3_before
    if before is None:
        os.environ.pop("QKF_CACHE_DIR", None)
    else:
        os.environ["QKF_CACHE_DIR"] = before


@pytest.fixture(scope="session")
def ray_cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One local Ray cluster (2 CPUs) for every test of this process that runs the ``ray``
    backend, which uses a cluster already started (``qkf.core.montecarlo``) and leaves it
    running. Yields a folder on its workers' import path, with the checkout, for modules a
    test writes (a user's method): Ray's workers take the environment of the process that
    started the cluster, so a later module is importable there only from a folder named
    at the start. A cluster and its workers' first imports cost 10–20 s; shared, once per
    test process (at most one per pytest-xdist worker) instead of once per test. CI installs
    the extra: there the backend is tested, not skipped."""
    ray = __import__("ray") if os.environ.get("CI") else pytest.importorskip("ray")
    modules = tmp_path_factory.mktemp("ray_modules")
    path = os.pathsep.join(p for p in (str(modules), str(ROOT), os.environ.get("PYTHONPATH")) if p)
    with pytest.MonkeyPatch.context() as env:
        env.setenv("PYTHONPATH", path)
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield modules
    finally:
        ray.shutdown()


PLACEHOLDER_PNG = placeholder_png()  # what an unrendered figure writes


_MODULES_THAT_RENDER: dict[str, bool] = {}


def _marked(item: pytest.Item) -> bool:
    return item.get_closest_marker("figures") is not None


def _module_renders(item: pytest.Item) -> bool:
    """Whether a test of ``item``'s module is marked ``figures``: the fixtures of that module
    (set up by whichever of its tests comes first) may write figures a marked test reads."""
    key = item.nodeid.split("::")[0]
    if key not in _MODULES_THAT_RENDER:
        _MODULES_THAT_RENDER[key] = any(
            _marked(i) for i in item.session.items if i.nodeid.split("::")[0] == key
        )
    return _MODULES_THAT_RENDER[key]


def _render(on: bool) -> None:
    """Render figures from now on (``on``), here and in the processes a test starts (through
    ``qkf.core.plotting.PLACEHOLDER_ENV``, which they inherit), or write placeholders."""
    os.environ[PLACEHOLDER_ENV] = "" if on else "1"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item: pytest.Item) -> Iterator[None]:
    # fixtures of every scope are set up here, module and session ones included
    _render(_marked(item) or _module_renders(item))
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    _render(_marked(item))
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item: pytest.Item) -> Iterator[None]:
    _render(False)
    yield


@pytest.fixture(scope="session", autouse=True)
def _figures_built_but_not_rendered() -> Iterator[None]:
    """Every figure is built (its plotting code runs), but rendered only for tests marked
    ``figures``: the rendering is matplotlib's layout of the ticks and labels, 0.3–5 s a
    figure and about a quarter of the whole suite's time (356 figures, 440 worker-seconds,
    measured with a timer in ``figure_png``). Elsewhere ``Figure.savefig`` writes a 1 × 1
    PNG, so file lists and PNG signatures stay checkable. Fixtures render when a test of
    their module is marked (they may be set up by an unmarked test of it first); a module
    fixture that rendered every figure of a families study took 20 of its 24 s. Commands a
    test runs in another process write placeholders the same way (the environment variable
    ``qkf.core.plotting.PLACEHOLDER_ENV``: a short ``qkf bench`` spent 5 of its 8 s on its
    figures)."""
    from matplotlib.figure import Figure

    real = Figure.savefig

    def savefig(self: Figure, fname: object, *args: object, **kwargs: object) -> None:
        if not os.environ.get(PLACEHOLDER_ENV):
            real(self, fname, *args, **kwargs)  # type: ignore[arg-type]
        elif hasattr(fname, "write"):
            fname.write(PLACEHOLDER_PNG)
        else:
            Path(str(fname)).write_bytes(PLACEHOLDER_PNG)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Figure, "savefig", savefig)
        yield
