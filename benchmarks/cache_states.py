"""The same run in every state of numba's on-disk cache, compared bit for bit
(docs/performance.md, "A fresh compile and the cached code").

Run: ``.venv/bin/python benchmarks/cache_states.py --out DIR [--methods all]``. Each state is a
new process with ``NUMBA_CACHE_DIR`` set, that runs a short ``qkf bench paper`` (in-process) and
short rollouts of the single (v0) and the batched (v3) environment:

* ``cold``: an empty cache: everything is compiled in the process;
* ``warm``: the cache that ``cold`` wrote;
* ``warm_preloaded``: the same, but the process first loads every cached function of ``qkf``,
  callees first (nothing is compiled);
* ``writer_a``, ``writer_b``: two processes started at once on another empty cache, in
  different orders (``writer_b`` first compiles the batched Kalman primitives, as a pytest
  worker that ran another test first would);
* ``read``: the cache that the two writers wrote.

It prints the largest relative difference of every state from ``cold``, per output file and
method, and exits 1 if any output differs. ``compare A B`` compares two state folders, for
example the ``read`` folder of a cache that ``pytest -n 2`` wrote::

    NUMBA_CACHE_DIR=/tmp/nc NUMBA_NUM_THREADS=1 .venv/bin/python -m pytest -n 2 tests/...
    NUMBA_CACHE_DIR=/tmp/nc .venv/bin/python benchmarks/cache_states.py probe /tmp/mixed bench,env
    .venv/bin/python benchmarks/cache_states.py compare DIR/warm /tmp/mixed

``probe OUT STEPS`` is one such process (``STEPS``: an order of ``bench``, ``env``,
``kalman``, ``preload``); tests/test_cache_states.py runs it.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

ALL_METHODS = "kf,kf-tuned,sage-husa,qkf,mmae,imm,fading,vbakf,covariance-matching,batch"
BENCH_FILES = ("rms.csv", "trials.csv", "kappa.csv", "nees.csv")
OVERRIDES = ["scenario.duration_s=1800"]
# --- one process ----------------------------------------------------------------------------


def bench(out: Path, methods: str, trials: int) -> None:
    from qkf.cli import app

    args = ["bench", "paper", "--trials", str(trials), "--seed", "9100", "--methods", methods]
    args += ["--set", "scenario.duration_s=900", "--quiet", "--out", str(out / "bench")]
    # --no-cache: from the results cache every state after the first would read the first
    # one's numbers back instead of computing them with its own compiled code
    args += ["--no-cache"]
    app(args, standalone_mode=False)


def env(out: Path) -> None:
    from envs.transfer_alignment import BatchedTransferAlignmentEnv, TransferAlignmentEnv

    single = TransferAlignmentEnv(
        "paper", reward="likelihood", observation="v0", overrides=OVERRIDES
    )
    obs, _ = single.reset(seed=123)
    rng = np.random.default_rng(5)
    observations, rewards, errors = [obs], [], []
    done = False
    while not done:
        obs, reward, terminated, truncated, info = single.step(int(rng.integers(11)))
        observations.append(obs)
        rewards.append(reward)
        errors.append(info["errors"])
        done = terminated or truncated
    arrays: dict[str, Any] = {
        "single_obs": np.array(observations),
        "single_reward": np.array(rewards),
        "single_errors": np.array(errors),
    }
    batched = BatchedTransferAlignmentEnv(
        8, "paper", reward="likelihood", observation="v3", overrides=OVERRIDES
    )
    b_obs, _ = batched.reset(seed=321)
    b_observations, b_rewards = [b_obs], []
    for _ in range(60):
        b_obs, b_reward, _, _, _ = batched.step(rng.integers(11, size=8))
        b_observations.append(b_obs)
        b_rewards.append(b_reward)
    arrays |= {"batched_obs": np.array(b_observations), "batched_reward": np.array(b_rewards)}
    np.savez(out / "env.npz", **arrays)


def kalman(out: Path) -> None:
    from qkf.core.kalman import predict, update

    rng = np.random.default_rng(0)
    x = rng.standard_normal((3, 4))
    p = np.tile(np.eye(4), (3, 1, 1))
    predict(x, p, np.eye(4), 0.1 * np.eye(4))
    update(x, p, rng.standard_normal((3, 2)), rng.standard_normal((2, 4)), np.eye(2))


COMPILED_MODULES = (  # callees before callers
    "qkf.core.quat",
    "qkf.core.kalman",
    "qkf.transfer_alignment.model_compiled",
    "qkf.transfer_alignment.kernel",
    "qkf.transfer_alignment.filter",
    "qkf.transfer_alignment.metrics",
    "qkf.transfer_alignment.methods.bank_compiled",
    "qkf.transfer_alignment.methods.vbakf_compiled",
    "qkf.transfer_alignment.methods.batch.dense",
    "qkf.transfer_alignment.methods.batch.sensitivity",
    "qkf.transfer_alignment.methods.batch.forward",
    "qkf.transfer_alignment.methods.batch.smoother",
    "qkf.transfer_alignment.methods.batch.solver",
)


def preload(out: Path) -> None:
    """Load every cached signature of the compiled functions of :data:`COMPILED_MODULES`,
    callees first (the modules in that order, each in source order), as a process that
    compiles them would meet them. Before the fix this alone turned a warm process's numbers
    into a cold one's (docs/performance.md)."""
    import importlib

    from numba.core.registry import CPUDispatcher

    for name in COMPILED_MODULES:
        module = importlib.import_module(name)
        found = [v for v in vars(module).values() if isinstance(v, CPUDispatcher)]
        for disp in sorted(found, key=lambda d: d.py_func.__code__.co_firstlineno):
            index = getattr(getattr(disp, "_cache", None), "_cache_file", None)
            if disp.py_func.__module__ != name or index is None:
                continue
            for key in index._load_index():
                disp.compile(key[0])  # loads from the cache (compiles if it is not there)


def probe(out: Path, steps: str, methods: str, trials: int) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for step in steps.split(","):
        if step == "bench":
            bench(out, methods, trials)
        elif step == "env":
            env(out)
        elif step == "kalman":
            kalman(out)
        elif step == "preload":
            preload(out)
        else:
            raise SystemExit(f"unknown step {step!r}")


# --- the states -----------------------------------------------------------------------------


def start(cache: Path, out: Path, steps: str, methods: str, trials: int) -> subprocess.Popen[bytes]:
    """One probe process on the cache folder ``cache`` (one numba thread, this checkout)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), NUMBA_NUM_THREADS="1")
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
    out.parent.mkdir(parents=True, exist_ok=True)
    log = (out.parent / f"{out.name}.log").open("wb")
    cmd = [sys.executable, __file__, "probe", str(out), steps, "--methods", methods]
    return subprocess.Popen([*cmd, "--trials", str(trials)], env=env, stdout=log, stderr=log)


def _csv(path: Path) -> list[list[str]]:
    with path.open() as f:
        return list(csv.reader(f))


def differences(a: Path, b: Path) -> dict[str, float]:
    """Largest relative difference per output file and method (bench) or array (env); only
    the outputs that differ."""
    out: dict[str, float] = {}
    for name in BENCH_FILES:
        if not (a / "bench" / name).exists():
            continue
        ra, rb = _csv(a / "bench" / name), _csv(b / "bench" / name)
        if ra == rb:
            continue
        header = ra[0]
        for xa, xb in zip(ra[1:], rb[1:], strict=True):
            key = f"{name} {xa[header.index('method')] if 'method' in header else ''}".strip()
            for u, v in zip(xa, xb, strict=True):
                if u != v:
                    x, y = float(u), float(v)
                    rel = abs(x - y) / max(abs(x), abs(y), 1e-300)
                    out[key] = max(out.get(key, 0.0), rel)
    with np.load(a / "env.npz") as ea, np.load(b / "env.npz") as eb:
        for key in ea.files:
            x, y = ea[key].astype(float), eb[key].astype(float)
            if not np.array_equal(x, y, equal_nan=True):
                rel = np.abs(x - y) / np.maximum(np.maximum(np.abs(x), np.abs(y)), 1e-300)
                out[f"env {key}"] = float(np.nanmax(rel))
    return out


def report(reference: Path, other: Path) -> bool:
    diff = differences(reference, other)
    if not diff:
        print(f"{other.name}: bit-identical to {reference.name}")
        return True
    print(f"{other.name}: differs from {reference.name}")
    for key, rel in sorted(diff.items()):
        print(f"    {key:32s} {rel:.2g}")
    return False


def run(out: Path, methods: str, trials: int) -> bool:
    if out.exists():
        shutil.rmtree(out)
    single, parallel = out / "cache_single", out / "cache_parallel"

    def wait(*procs: subprocess.Popen[bytes]) -> None:
        for proc in procs:
            if proc.wait() != 0:
                raise SystemExit(f"{proc.args!r} failed: see its log in {out}")

    wait(start(single, out / "cold", "bench,env", methods, trials))
    wait(start(single, out / "warm", "bench,env", methods, trials))
    wait(start(single, out / "warm_preloaded", "preload,bench,env", methods, trials))
    wait(
        start(parallel, out / "writer_a", "env,bench", methods, trials),
        start(parallel, out / "writer_b", "kalman,bench,env", methods, trials),
    )
    wait(start(parallel, out / "read", "bench,env", methods, trials))
    states = ("warm", "warm_preloaded", "writer_a", "writer_b", "read")
    return all([report(out / "cold", out / s) for s in states])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="command")
    p = sub.add_parser("probe")
    p.add_argument("out", type=Path)
    p.add_argument("steps")
    c = sub.add_parser("compare")
    c.add_argument("a", type=Path)
    c.add_argument("b", type=Path)
    for parser in (ap, p):
        parser.add_argument("--methods", default=ALL_METHODS, help="bench methods (default: all)")
        parser.add_argument("--trials", type=int, default=4)
    ap.add_argument("--out", type=Path, default=Path("results/cache_states"))
    args = ap.parse_args()
    if args.command == "probe":
        probe(args.out, args.steps, args.methods, args.trials)
    elif args.command == "compare":
        sys.exit(0 if report(args.a, args.b) else 1)
    else:
        sys.exit(0 if run(args.out, args.methods, args.trials) else 1)


if __name__ == "__main__":
    main()
