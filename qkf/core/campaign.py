"""Campaigns: several cases of one problem, each run into its own folder of one output folder.

A study or a sweep (:mod:`qkf.transfer_alignment.study`) is a campaign: it runs a list of
cases, writes each case folder whole as soon as that case is done, then the summary files
beside them, and keeps a ``run.json`` (:mod:`qkf.core.manifest`) that lists every file it
wrote. Nothing here knows a problem: a problem supplies its cases (anything with a
``folder``) and a :class:`CaseRunner` that runs one case, writes its folder, and reads a
finished one back.

What the output folder may hold is checked before any work (:meth:`Campaign.prepare`): an
interrupted campaign is finished with ``resume`` (finished cases are read back, not
recomputed) or replaced with ``overwrite`` (a staging folder swapped in whole at the end); a
folder holding anything qkf did not write is refused whatever the flags, never deleted and
never written into.

Extension point: a new problem's campaign is a :class:`Campaign` (its kind and the summary
files it writes) and a :class:`CaseRunner` of its own (docs/architecture.md, "Recipe: add a
problem").
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

from qkf.core.config import ConfigError
from qkf.core.io import OutputError, check_output_dir, slug, staged_directory
from qkf.core.manifest import MANIFEST as RUN_FILE
from qkf.core.manifest import manifest, read_manifest, write_manifest


class Case(Protocol):
    """What a campaign needs of a case: the name of its folder under the output folder."""

    @property
    def folder(self) -> str: ...


CaseT = TypeVar("CaseT", bound=Case)
CaseT_contra = TypeVar("CaseT_contra", bound=Case, contravariant=True)
ResultT = TypeVar("ResultT")


class CaseRunner(Protocol[CaseT_contra, ResultT]):
    """How a problem runs one case of a campaign, writes it and reads it back."""

    def run(self, case: CaseT_contra) -> ResultT:
        """The result of a case, computed."""
        ...

    def write(self, result: ResultT, folder: Path) -> None:
        """Write a result's folder whole (as one: a staged directory)."""
        ...

    def reuse(self, case: CaseT_contra, folder: Path) -> ResultT | None:
        """The result ``folder`` holds if it is a finished run of exactly this case, else
        None (then the case is run again)."""
        ...


def case_folder(label: str) -> str:
    """The folder of a case: its label made file-name safe (``attitude + rate`` →
    ``attitude_rate``)."""
    return slug(label).strip("_") or "case"


def _manifest(folder: Path) -> dict[str, Any] | None:
    """The qkf manifest (``run.json``) of ``folder``, or None if it holds none."""
    try:
        return read_manifest(folder)
    except (ConfigError, OSError):
        return None


def _listed(info: dict[str, Any] | None) -> set[str]:
    """The files a manifest says its run wrote (relative to its folder)."""
    files = None if info is None else info.get("files")
    return set(map(str, files)) if isinstance(files, list) else set()


@dataclass(frozen=True)
class Campaign:
    """A kind of campaign (``study``, ``sweep``) and the summary files it may write beside
    its case folders (recognised as its own when a run is resumed or replaced)."""

    kind: str
    summary_files: frozenset[str]

    def prepare(self, out: str | Path, resume: bool, overwrite: bool) -> None:
        """Refuse, before any work, an output folder this campaign may not use (module
        docstring); a refusal suggests only a flag that works."""
        out = check_output_dir(out)  # as given: Path('') would be the working directory
        if resume and overwrite:
            raise OutputError("--resume and --overwrite exclude each other")
        if not out.is_dir() or not any(out.iterdir()):
            return
        found = _manifest(out)
        if found is not None and found["kind"] != self.kind:
            raise OutputError(
                f"{out}: holds a qkf {found['kind']} run, not a {self.kind} run; "
                "choose another --out"
            )
        foreign = self.not_ours(out, found)
        if foreign:
            shown = ", ".join(foreign[:4]) + (", …" if len(foreign) > 4 else "")
            if found is None:
                raise OutputError(
                    f"{out}: holds files that are not a qkf run ({shown}); "
                    "choose another --out or empty the folder"
                )
            raise OutputError(
                f"{out}: holds files qkf did not write beside its earlier {self.kind} run "
                f"({shown}); move them out of the folder or choose another --out"
            )
        try:
            # replaced whole at the end only if it holds nothing but an earlier run of this
            # kind (qkf.core.io.staged_directory): checked now, not after the work
            check_output_dir(out, self.kind)
            replaceable = None
        except OutputError as exc:
            replaceable = exc
        if overwrite and replaceable is not None:
            raise replaceable
        if not (resume or overwrite):
            hint = "--resume finishes it" + (
                ", --overwrite replaces it" if replaceable is None else ""
            )
            raise OutputError(f"{out}: holds an earlier qkf {self.kind} run; {hint}")

    def not_ours(self, out: Path, root: dict[str, Any] | None) -> list[str]:
        """What no campaign wrote in ``out``, as paths relative to it (a folder with a
        trailing ``/``): any file but those the folder's ``run.json`` (``root``) or a case
        folder's own lists, the summary files and qkf's hidden staging folders. Without a
        ``run.json``, ``out`` holds no campaign: all its entries."""
        if root is None:
            return [f"{e.name}/" if e.is_dir() else e.name for e in sorted(out.iterdir())]
        listed = _listed(root)
        found = []
        for entry in sorted(out.iterdir()):
            if entry.name.startswith("."):
                continue
            if not entry.is_dir():
                if entry.name not in listed and entry.name not in self.summary_files:
                    found.append(entry.name)
                continue
            own = _listed(_manifest(entry))
            for p in sorted(entry.rglob("*")):
                rel = p.relative_to(entry).as_posix()
                if not p.is_dir() and rel not in own and f"{entry.name}/{rel}" not in listed:
                    found.append(f"{entry.name}/{rel}")
            if not any(entry.iterdir()):
                found.append(f"{entry.name}/")
        return found

    @contextmanager
    def output(self, out: Path, resume: bool, overwrite: bool) -> Iterator[Path]:
        """Where the campaign writes: ``out`` itself (fresh or resumed), or, with
        ``overwrite``, a staging folder swapped in whole at the end."""
        self.prepare(out, resume, overwrite)
        if overwrite:
            with staged_directory(out) as stage:
                yield stage
        else:
            out.mkdir(parents=True, exist_ok=True)
            yield out

    def record(self, where: Path, config: dict[str, Any], **run: Any) -> None:
        """``run.json`` of the campaign folder, with the list of every file under it (so that
        ``--overwrite`` may replace exactly these). Rewritten after each case: an interrupted
        run is a complete description of what it holds."""
        data = manifest(self.kind, config, **run)
        files = {p.relative_to(where).as_posix() for p in where.rglob("*") if p.is_file()}
        data["files"] = sorted(files | {RUN_FILE})
        write_manifest(where, data)

    def remove_stale(self, where: Path, keep: set[str]) -> None:
        """Remove what an earlier run left in ``where`` that this run did not write: case
        folders (recognised by their ``run.json``) and summary files."""
        for entry in where.iterdir():
            if entry.name in keep:
                continue
            if entry.is_dir() and (entry / RUN_FILE).is_file():
                shutil.rmtree(entry)
            elif entry.is_file() and entry.name in self.summary_files:
                entry.unlink()


def run_cases(
    cases: Sequence[CaseT],
    runner: CaseRunner[CaseT, ResultT],
    where: Path,
    resume: bool = False,
    on_case: Callable[[CaseT, Path, bool], None] | None = None,
    on_start: Callable[[int, int, CaseT], None] | None = None,
) -> list[ResultT]:
    """Run the cases into ``where/<case.folder>/``, each written whole as soon as it is done;
    with ``resume``, a case whose folder holds its finished run is read back instead
    (:meth:`CaseRunner.reuse`). ``on_start(i, n, case)`` (1-based ``i`` of ``n``) is called
    before each case, ``on_case(case, folder, reused)`` after each."""
    results = []
    for i, case in enumerate(cases, 1):
        if on_start is not None:
            on_start(i, len(cases), case)
        folder = where / case.folder
        result = runner.reuse(case, folder) if resume else None
        reused = result is not None
        if result is None:
            result = runner.run(case)
            runner.write(result, folder)
        results.append(result)
        if on_case is not None:
            on_case(case, folder, reused)
    return results


__all__ = ["RUN_FILE", "Campaign", "Case", "CaseRunner", "case_folder", "run_cases"]
