"""numba's on-disk cache, kept consistent across modules (docs/performance.md).

numba caches each compiled function next to its source (``__pycache__/*.nbi`` index,
``*.nbc`` code) and checks a cache entry against that one source file only. A compiled
function that calls compiled code of another module carries its own copy of that code. After
an edit of ``qkf/transfer_alignment/kernel.py`` (or a ``git pull`` that changes it), the kernel
recompiles, but the cached IMM/MMAE banks of ``methods/bank_compiled.py`` would still run the
old kernel, silently.

:func:`discard_stale_caches` closes that gap when ``qkf`` is imported. It fingerprints every
module of the package that holds compiled code. When the fingerprint differs from the one the
caches were written under, it removes the package's numba cache files, so that everything
recompiles together (once, on first use). It only touches ``*.nbi``/``*.nbc`` files in the
package's own ``__pycache__`` folders, and the stamp file it writes there.

Not covered: caches that numba keeps outside the source tree (``NUMBA_CACHE_DIR`` set, or a
read-only install). Those go stale only where the installed sources change; an upgrade by pip
writes every file anew, so numba's own check catches it.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

STAMP_NAME = "numba-sources.sha256"
"""The fingerprint the cache files were written under, in ``<root>/__pycache__/``."""

_MARKERS = (b"njit", b"kernel_jit")  # a module that holds compiled code mentions one of them


def compiled_sources_digest(root: Path) -> str:
    """SHA-256 (hex) over the relative paths and contents of the ``*.py`` files under ``root``
    that hold compiled code."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        text = path.read_bytes()
        if any(marker in text for marker in _MARKERS):
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(hashlib.sha256(text).digest())
    return digest.hexdigest()


def discard_stale_caches(root: Path) -> bool:
    """Remove numba's cache files under ``root`` if its compiled modules changed since they were
    written; True if any were removed.

    Does nothing where the fingerprint matches, and gives up quietly where the tree is not
    writable (numba then caches elsewhere). Several processes may run it at once: removal
    tolerates files that are already gone, numba recompiles what it cannot load, and the stamp
    is replaced atomically.
    """
    stamp = root / "__pycache__" / STAMP_NAME
    digest = compiled_sources_digest(root)
    try:
        if stamp.read_text(encoding="ascii") == digest:
            return False
    except (OSError, UnicodeDecodeError):
        pass  # no stamp yet, or unreadable: treat as changed
    removed = False
    for folder in root.rglob("__pycache__"):
        for pattern in ("*.nbi", "*.nbc"):
            for path in folder.glob(pattern):
                try:
                    path.unlink()
                    removed = True
                except FileNotFoundError:  # another process was first
                    pass
                except OSError:  # not ours to remove (read-only tree): numba caches elsewhere
                    return removed
    try:
        stamp.parent.mkdir(exist_ok=True)
        partial = stamp.with_name(f"{STAMP_NAME}.{os.getpid()}.tmp")
        partial.write_text(digest, encoding="ascii")
        os.replace(partial, stamp)
    except OSError:
        pass  # read-only tree
    return removed
