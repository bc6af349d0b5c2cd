"""Where a cold start spends its time in LLVM: every numba compilation of a pytest run (or of
any Python command), per function, signature and test (docs/performance.md, "The test
suite's time").

Run::

    .venv/bin/python benchmarks/compile_census.py run --log DIR [-- PYTEST ARGS]
    .venv/bin/python benchmarks/compile_census.py report DIR [--top 25]

``run`` starts pytest (``-n auto`` unless other arguments are given) on an empty numba cache
(``DIR/numba_cache``: a cold start, as a fresh clone's ``make test``), with this file loaded as
a pytest plugin in every worker; each process appends one line per compilation to
``DIR/<pid>.tsv``: seconds, nesting depth (0: compiled for a call from Python; deeper: a
callee compiled on the way), function, test, signature. Then it prints the report.

``report`` sums the top-level compilations per process, lists the costliest, the parallel row
loops against the per-row routine inside them, and the functions that more than one process
compiled with the same signature (what two pytest-xdist workers paid twice). Compilations in
processes that a test starts itself (``subprocess``) are not seen. numba's own events
(``numba.core.event``, ``numba:compile``) fire for real compilations only, not for code loaded
from the cache.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from numba.core import event

LOG_ENV = "QKF_COMPILE_LOG"
_state: dict[str, Any] = {"test": "(collection)", "starts": []}


class _Listener(event.Listener):
    """Times each ``numba:compile`` event (nested ones inside) and appends a line per event."""

    def __init__(self, folder: Path) -> None:
        super().__init__()
        self.path = folder / f"{os.getpid()}.tsv"

    def on_start(self, event: Any) -> None:
        _state["starts"].append(time.perf_counter())

    def on_end(self, event: Any) -> None:
        began = _state["starts"].pop() if _state["starts"] else float("nan")
        data = event.data or {}
        func = getattr(data.get("dispatcher"), "py_func", None)
        name = f"{getattr(func, '__module__', '?')}.{getattr(func, '__qualname__', '?')}"
        line = [
            f"{time.perf_counter() - began:.3f}",
            str(len(_state["starts"])),
            name,
            _state["test"],
            str(data.get("args")),
        ]
        with self.path.open("a", encoding="utf-8") as f:
            f.write("\t".join(line) + "\n")


def pytest_configure(config: pytest.Config) -> None:
    """Pytest plugin entry: listen to numba's compile events when ``QKF_COMPILE_LOG`` is set."""
    folder = os.environ.get(LOG_ENV)
    if folder and not _state.get("listening"):  # once per process, however often configured
        event.register("numba:compile", _Listener(Path(folder)))
        _state["listening"] = True


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    _state["test"] = item.nodeid
    yield


def _rows(folder: Path) -> list[tuple[str, float, int, str, str, str]]:
    rows = []
    for path in sorted(folder.glob("*.tsv")):
        for line in path.read_text(encoding="utf-8").splitlines():
            seconds, depth, name, test, sig = line.split("\t")
            rows.append((path.stem, float(seconds), int(depth), name, test, sig))
    return rows


def report(folder: Path, top: int) -> None:
    """Print the census of the logs in ``folder``."""
    rows = _rows(folder)
    if not rows:
        raise SystemExit(f"{folder}: no compile logs (*.tsv)")
    first = [r for r in rows if r[2] == 0]
    per_process: dict[str, float] = defaultdict(float)
    for pid, seconds, *_ in first:
        per_process[pid] += seconds
    total = sum(per_process.values())
    print(f"top-level compile time: {total:.1f} s over {len(per_process)} processes")
    for pid, seconds in sorted(per_process.items()):
        print(f"  process {pid}: {seconds:.1f} s")
    print(f"\ncostliest top-level compilations ({top}):")
    for pid, seconds, _, name, test, _ in sorted(first, key=lambda r: -r[1])[:top]:
        print(f"  {seconds:6.1f} s  {name}  [{pid}] {test}")
    # a parallel row loop (``<row>_rows``) against its per-row routine compiled inside it
    print("\nrow loops: the loop's own cost beyond the per-row routine it calls")
    routines = {r[3] for r in rows}
    for pid, seconds, _, name, test, _ in first:
        if not name.endswith("_rows") or name[:-5] not in routines:
            continue  # not a loop over a compiled per-row routine
        inner = [r for r in rows if r[0] == pid and r[4] == test and r[3] == name[:-5]]
        inside = max((r[1] for r in inner), default=0.0)
        print(
            f"  {seconds:6.1f} s  {name}  (routine {inside:.1f} s, loop {seconds - inside:.1f} s)"
        )
    seen: dict[tuple[str, str], dict[str, float]] = defaultdict(dict)
    for pid, seconds, _, name, _, sig in first:
        seen[(name, sig)][pid] = seen[(name, sig)].get(pid, 0.0) + seconds
    twice = sorted(((min(v.values()), k[0]) for k, v in seen.items() if len(v) > 1), reverse=True)
    print(f"\ncompiled by more than one process: {sum(s for s, _ in twice):.1f} s paid again")
    for seconds, name in twice[:top]:
        print(f"  {seconds:6.1f} s  {name}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="a pytest run on an empty numba cache, then the report")
    run.add_argument("--log", type=Path, required=True, help="an empty or new folder")
    run.add_argument("--top", type=int, default=25)
    run.add_argument("pytest_args", nargs="*", help="after --: pytest's arguments")
    rep = sub.add_parser("report", help="the report of a folder of logs")
    rep.add_argument("folder", type=Path)
    rep.add_argument("--top", type=int, default=25)
    args = parser.parse_args()
    if args.command == "report":
        report(args.folder, args.top)
        return
    folder: Path = args.log.resolve()
    if folder.exists() and any(folder.iterdir()):
        raise SystemExit(f"--log {folder}: not empty (the census needs its own folder)")
    (folder / "numba_cache").mkdir(parents=True)
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(folder / "numba_cache"), NUMBA_NUM_THREADS="1")
    env[LOG_ENV] = str(folder)
    env["PYTHONPATH"] = os.pathsep.join(
        filter(None, [str(root / "benchmarks"), str(root), env.get("PYTHONPATH")])
    )
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "compile_census", "-p", "no:cacheprovider"]
    cmd += args.pytest_args or ["-n", "auto"]
    began = time.perf_counter()
    code = subprocess.call(cmd, cwd=root, env=env)
    print(f"\npytest exited {code} after {time.perf_counter() - began:.0f} s\n")
    report(folder, args.top)
    raise SystemExit(code)


if __name__ == "__main__":
    main()
