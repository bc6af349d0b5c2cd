"""The same numbers from every state of numba's on-disk cache (docs/performance.md, "A fresh
compile and the cached code").

Before the fix, a compiled function called the first copy of each compiled callee that the
process had loaded, and which one that was depended on how the cache had been filled. Now every
compiled function calls the copies compiled into its own object code (qkf.core.jit).
"""

from __future__ import annotations

import json
import os
import pickle
import re
import struct
import subprocess
import sys
from pathlib import Path

import numba as nb
import numpy as np
import pytest

from qkf.core.jit import LINK_TAG, internalize_linked_functions

ROOT = Path(__file__).resolve().parents[1]
PROBE = ROOT / "benchmarks" / "cache_states.py"  # its `probe`: a short bench and rollouts
STB_WEAK, STT_FUNC, SHT_SYMTAB = 2, 2, 2


def _function_symbols(obj: bytes) -> dict[str, int]:
    """Binding (STB_*) of each function symbol defined in an ELF64 little-endian object."""
    shoff, shentsize, shnum = (
        struct.unpack_from("<Q", obj, 0x28)[0],
        *struct.unpack_from("<HH", obj, 0x3A),
    )
    sections = [struct.unpack_from("<IIQQQQIIQQ", obj, shoff + i * shentsize) for i in range(shnum)]
    out: dict[str, int] = {}
    for _, sh_type, _, _, offset, size, link, _, _, entsize in sections:
        if sh_type != SHT_SYMTAB:
            continue
        strtab = sections[link][4]
        for pos in range(offset, offset + size, entsize):
            st_name, st_info, _, st_shndx = struct.unpack_from("<IBBH", obj, pos)
            if st_info & 0xF == STT_FUNC and st_shndx != 0:
                end = obj.index(b"\0", strtab + st_name)
                out[obj[strtab + st_name : end].decode()] = st_info >> 4
    return out


def _elf() -> bool:
    return sys.platform.startswith("linux")


@nb.njit
def _fib(n: int) -> int:  # recursive: LLVM cannot inline all of it into a caller
    if n < 2:
        return n
    return _fib(n - 1) + _fib(n - 2)


@nb.njit
def _calls_fib(n: int) -> int:
    return _fib(n) + 1


def test_a_caller_runs_its_own_copy_of_a_compiled_callee() -> None:
    assert _calls_fib(10) == 56
    library = _calls_fib.overloads[_calls_fib.signatures[0]].library
    defined = [f for f in library._final_module.functions if not f.is_declaration]
    copies = [f for f in defined if "_fib" in f.name and "calls_fib" not in f.name]
    assert copies, "the test needs a copy of _fib that LLVM did not inline"
    assert all(f.linkage.name == "internal" for f in copies)
    assert not [f.name for f in defined if f.linkage.name == "linkonce_odr"]
    if _elf():  # in the machine code: local symbols, not weak ones the JIT linker could rebind
        symbols = _function_symbols(library._get_compiled_object())
        fib = [b for name, b in symbols.items() if "_fib" in name and "calls_fib" not in name]
        assert fib and STB_WEAK not in fib
    assert internalize_linked_functions(library._final_module) == 0  # nothing left to do
    assert LINK_TAG in library.codegen.magic_tuple()  # and old caches are not loaded


@nb.njit(parallel=True)
def _parallel_sum(x: np.ndarray) -> float:
    total = 0.0
    for i in nb.prange(x.shape[0]):
        total += _fib(int(x[i]))
    return total


@nb.guvectorize(["void(float64[:], float64[:])"], "(n)->()")
def _gu_sum(x: np.ndarray, out: np.ndarray) -> None:
    out[0] = x.sum()


def test_parallel_loops_and_gufuncs_still_work() -> None:
    """A prange loop's wrapper (weak_odr in its own library) is a copy in its caller's, and
    bound there too; a gufunc's wrapper is its library's own entry point and stays global."""
    assert _parallel_sum(np.arange(12.0)) == sum([0, 1, 1, 2, 3, 5, 8, 13, 21, 34, 55, 89])
    library = _parallel_sum.overloads[_parallel_sum.signatures[0]].library
    linkages = {f.linkage.name for f in library._final_module.functions if not f.is_declaration}
    assert linkages <= {"external", "internal", "private"}
    if _elf():
        assert STB_WEAK not in _function_symbols(library._get_compiled_object()).values()
    np.testing.assert_array_equal(_gu_sum(np.arange(6.0).reshape(2, 3)), [3.0, 12.0])


def test_every_compiling_module_installs_the_binding() -> None:
    """The binding only holds for code compiled after qkf.core.jit was imported, so every
    module with compiled code imports it itself."""
    missing = []
    for folder in ("qkf", "envs"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            if path.name == "jit.py" or not re.search(r"@(nb\.njit|njit|kernel_jit)\b", text):
                continue
            if not re.search(r"^(from qkf\.core\.jit import|import qkf\.core\.jit)", text, re.M):
                missing.append(str(path.relative_to(ROOT)))
    assert not missing


def _probe(cache: Path, out: Path, steps: str) -> subprocess.Popen[bytes]:
    """A new process on the cache folder ``cache``: ``steps`` (an order of bench, env and
    kalman) of ``benchmarks/cache_states.py probe``, outputs into ``out``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), NUMBA_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    log = (out.parent / f"{out.name}.log").open("wb")
    # two trials: the bench runs the kernel's and the VB epoch's serial loops (the batched
    # environment of the probe runs the kernel's parallel one)
    cmd = [sys.executable, str(PROBE), "probe", str(out), steps, "--methods", "kf,vbakf"]
    cmd += ["--trials", "2"]
    return subprocess.Popen(cmd, env=env, stdout=log, stderr=log)


def _wait(*procs: subprocess.Popen[bytes]) -> None:
    for proc in procs:
        assert proc.wait(timeout=1200) == 0, proc.args


def _computed_everything(out: Path) -> bool:
    """Whether the probe's bench ran every method itself: a result read back from qkf's
    results cache would compare the first state's numbers with themselves."""
    counts = json.loads((out / "bench" / "run.json").read_text())["cache"]
    return all(c["hit"] == 0 and c["off"] == 1 for c in counts.values())


def _outputs(out: Path) -> dict[str, bytes]:
    files = {name: (out / "bench" / name).read_bytes() for name in ("rms.csv", "trials.csv")}
    with np.load(out / "env.npz") as env:
        files |= {key: env[key].tobytes() for key in sorted(env.files)}
    return files


def _cached_weak_functions(cache: Path) -> list[str]:
    weak = []
    for path in sorted(cache.rglob("*.nbc")):
        (_, kind, data) = pickle.loads(path.read_bytes())[0]
        assert kind == "object"
        symbols = _function_symbols(data[0])
        weak += [f"{path.name}: {name}" for name, b in symbols.items() if b == STB_WEAK]
    return weak


@pytest.mark.slow
def test_bench_and_environments_are_bit_identical_in_every_cache_state(tmp_path: Path) -> None:
    """Two processes that compile everything into one fresh cache at the same time, in
    different orders (as pytest-xdist workers do), and a process that loads what those two
    wrote: the same bits from the compiled and the loaded code.

    The methods are ``kf`` (the kernel) and ``vbakf`` (its own compiled module over the shared
    model functions): before the fix the loaded code moved ``vbakf`` by 1.9e-9, the single
    environment's reward by 1.7e-10, and ``kf`` by 5.1e-9 in a cache two writers filled. The
    state from one writer, the IMM/MMAE bank and every other method are
    ``benchmarks/cache_states.py``'s (three more cold compiles: minutes)."""
    shared = tmp_path / "cache_parallel"
    _wait(
        _probe(shared, tmp_path / "writer_a", "env,bench"),
        _probe(shared, tmp_path / "writer_b", "kalman,bench,env"),
    )
    _wait(_probe(shared, tmp_path / "read", "bench,env"))

    states = ("writer_a", "writer_b", "read")
    assert [s for s in states if not _computed_everything(tmp_path / s)] == []
    compiled = _outputs(tmp_path / "writer_a")
    for state in states[1:]:
        other = _outputs(tmp_path / state)
        assert [k for k in compiled if compiled[k] != other[k]] == [], state
    if _elf():
        assert _cached_weak_functions(shared) == []
