"""The numbers a user computes, written for two trees and compared byte for byte.

A restructure must not change what any command computes. This script runs a fixed set of
commands (the transfer-alignment bench on three presets with every method, the gyro bench
under every backend, the fusion and the alignment) into ``--out`` and prints a SHA-256 of each
result file that carries numbers (not the manifests, not the timings, not the figures). Run it
on the old tree and on the new one, then compare::

    python benchmarks/reference_outputs.py --out /tmp/ref_old            # in the old checkout
    python benchmarks/reference_outputs.py --out /tmp/ref_new --against /tmp/ref_old

``--against`` exits 1 and names the files that differ. Give each run an empty numba cache
(``NUMBA_CACHE_DIR=<new folder>``); the results cache is off for every command.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

BENCH_PRESETS = ("paper", "thermal_snap", "thermal_snap_random")
METHODS = (
    "kf,kf-tuned,sage-husa,qkf,mmae,imm,fading,vbakf,covariance-matching,batch,oracle,alarm-burst"
)
TRIALS = "8"
BENCH_FILES = ("rms.csv", "trials.csv", "kappa.csv", "paired.csv", "nees.csv")
GYRO_BACKENDS: tuple[tuple[str, list[str]], ...] = (
    ("local", []),
    ("pool", ["--workers", "2"]),
    ("ray", ["--backend", "ray"]),
)


def _qkf(*args: str) -> None:
    cmd = [sys.executable, "-m", "qkf", *args]
    print("$ qkf", " ".join(args), flush=True)
    # every result computed, none read back from the user's results cache: a cached entry is
    # the numbers of whatever numba cache state wrote it (docs/performance.md, "A cache
    # filled piecemeal"), not of this run
    env = {**os.environ, "QKF_NO_CACHE": "1"}
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=env)


def _supports(command: list[str], option: str) -> bool:
    """Whether a command of this tree has an option (older trees may lack one)."""
    res = subprocess.run(
        [sys.executable, "-m", "qkf", *command, "--help"], capture_output=True, text=True
    )
    return option in res.stdout


WRITTEN = ("bench", "gyros", "gyros_run", "fuse", "align", "digests.json")
"""What a run writes into ``--out``: all that a rerun replaces there."""


def prepare(out: Path) -> None:
    """Make ``out`` ready: created if absent; an earlier ``--out`` of this script (it holds
    ``digests.json``) loses what the script wrote there, nothing else; any other folder that is
    not empty is refused (``SystemExit`` 2, before any work)."""
    if out.exists() and not out.is_dir():
        raise SystemExit(f"--out: {out} is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / "digests.json").is_file():
        raise SystemExit(
            f"--out: {out} is not empty and holds no digests.json: not an earlier --out of this "
            "script, so nothing there is replaced; name an empty or new folder"
        )
    for name in WRITTEN:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    out.mkdir(parents=True, exist_ok=True)


def run(out: Path) -> dict[str, str]:
    """Run every command into ``out`` (:func:`prepare`); the digests of the files that carry
    numbers."""
    prepare(out)
    digests: dict[str, str] = {}
    for preset in BENCH_PRESETS:
        folder = out / "bench" / preset
        _qkf("bench", preset, "--methods", METHODS, "--trials", TRIALS, "--seed", "7",
             "--out", str(folder), "--quiet")  # fmt: skip
        for name in BENCH_FILES:
            digests[f"bench/{preset}/{name}"] = _digest(folder / name)
    gyro_options = ["--trials", "4", "--seed", "3", "--quiet"]
    for label, extra in GYRO_BACKENDS:
        if extra and not _supports(["gyros", "bench"], extra[0]):
            continue  # a tree whose gyro bench has no backends
        folder = out / "gyros" / label
        _qkf("gyros", "bench", "five_gyros", *gyro_options, *extra, "--out", str(folder))
        for path in sorted(folder.glob("*.csv")):
            digests[f"gyros/{label}/{path.name}"] = _digest(path)
    _qkf("gyros", "run", "five_gyros_y_misalignment", "--out", str(out / "gyros_run"))
    for name in ("fdi.csv", "calibration.csv"):
        digests[f"gyros_run/{name}"] = _digest(out / "gyros_run" / name)
    _qkf("fuse", "sca_acc_fusion", "--set", "simulation.duration_s=3600", "--quiet",
         "--out", str(out / "fuse"))  # fmt: skip
    for path in sorted((out / "fuse").glob("*.csv")):
        digests[f"fuse/{path.name}"] = _digest(path)
    _qkf("align", "alignment_three_sensors", "--out", str(out / "align"))
    for path in sorted((out / "align").glob("*.csv")):
        digests[f"align/{path.name}"] = _digest(path)
    return digests


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "missing"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, required=True,
        help="folder to write: new, empty, or an earlier --out (what it wrote is replaced)",
    )  # fmt: skip
    parser.add_argument("--against", type=Path, help="an earlier --out to compare with")
    args = parser.parse_args()
    digests = run(args.out)
    (args.out / "digests.json").write_text(json.dumps(digests, indent=2) + "\n")
    if args.against is None:
        print(f"{len(digests)} files; digests in {args.out / 'digests.json'}")
        return 0
    old = json.loads((args.against / "digests.json").read_text())
    differ = sorted(k for k in old.keys() & digests.keys() if old[k] != digests[k])
    only = sorted(old.keys() ^ digests.keys())
    same = len(old.keys() & digests.keys()) - len(differ)
    # every backend of the gyro bench against the local one of the old tree
    for key, value in digests.items():
        if key.startswith("gyros/") and not key.startswith("gyros/local/"):
            ref = "gyros/local/" + key.split("/", 2)[2]
            if old.get(ref) != value:
                differ.append(key)
    print(f"{same} files byte-identical, {len(differ)} differ, {len(only)} in one tree only")
    for k in differ:
        print(f"  differs: {k}")
    for k in only:
        print(f"  only in {'old' if k in old else 'new'}: {k}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
