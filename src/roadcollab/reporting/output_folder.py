"""Output folders that never cost a user their files: checked before any compute, staged, committed.

Rules (README "Output folders"):

* roadcollab writes into ``--out`` only when the folder is absent, empty, or a previous result of the
  *same* command, recognised by the manifest :data:`MANIFEST` it writes there (command, version and
  every file it wrote). Anything else is refused before any compute, with a suggestion.
* ``''``, ``.``, ``..``, ``/``, the home folder, the current folder and any folder that contains the
  current folder are refused; so is a folder that equals or contains an input of the run (a drive, a
  profile, a store, a fleet folder).
* A run writes into a hidden staging folder beside ``--out`` (``.NAME.partial-*``, same file system)
  and moves its files into place only when it has finished; a failed or interrupted run removes its
  staging folder and leaves the previous results untouched. A staging folder left by a killed run
  (``SIGKILL``) is removed by the next run into the same place, and only if it carries the staging
  mark (:data:`STAGING_MARK`) with the id of a process that no longer runs.
* Committing replaces only files the previous manifest lists (roadcollab wrote them) and adds the new
  ones; a file a user put into a previous result folder is kept.

Only the standard library is imported, so the check costs milliseconds before a command imports its
study.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import tempfile
import threading
from pathlib import Path
from typing import Iterable, Iterator

from .. import __version__
from ..errors import ParameterError

__all__ = ["MANIFEST", "STAGING_MARK", "check_output_folder", "staged_output", "check_output_file", "staged_file"]

#: The manifest of a result folder: ``{"roadcollab": version, "command": name, "files": [relative paths]}``.
MANIFEST = ".roadcollab-output.json"
#: The mark of a staging folder: ``{"pid": process id}`` of the run that made it.
STAGING_MARK = ".roadcollab-staging.json"


def _refuse(out, why: str, suggest: bool = True) -> ParameterError:
    tip = " (choose a new folder, e.g. a subfolder that does not exist yet)" if suggest else ""
    return ParameterError(f"--out {out}: {why}{tip}")


def _within(path: Path, folder: Path) -> bool:
    """Is ``path`` equal to or inside ``folder`` (both resolved)?"""
    return path == folder or folder in path.parents


def read_manifest(folder: Path) -> dict | None:
    """The manifest of ``folder`` (None if absent or unreadable: then it is not a roadcollab result)."""
    try:
        data = json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    ok = (isinstance(data, dict) and isinstance(data.get("command"), str) and isinstance(data.get("files"), list)
          and all(isinstance(f, str) for f in data["files"]))
    return data if ok else None


def _entries(folder: Path) -> list[str]:
    """Relative paths of every file and folder under ``folder`` (symlinks not followed)."""
    out: list[str] = []
    for root, dirs, files in os.walk(folder):
        rel = Path(root).relative_to(folder)
        out.extend(str(rel / n) if str(rel) != "." else n for n in dirs + files)
    return out


def _foreign(folder: Path, manifest: dict | None) -> list[str]:
    """Entries of ``folder`` that roadcollab did not write (not in the manifest, not the manifest itself)."""
    ours = set(manifest["files"]) if manifest else set()
    for f in list(ours):  # the folders holding our files are ours too
        ours.update(str(p) for p in Path(f).parents if str(p) != ".")
    return sorted(e for e in _entries(folder) if e != MANIFEST and e not in ours)


def check_output_folder(out, command: str, inputs: Iterable = ()) -> Path:
    """Refuse an ``--out`` folder that would put anything not written by roadcollab at risk.

    Parameters
    ----------
    out : str or Path
        The folder as the user typed it.
    command : str
        The subcommand (a previous result of another command is refused).
    inputs : iterable of str or Path
        Files and folders the run reads; ``out`` must neither equal nor contain any of them.

    Returns
    -------
    Path
        ``out``, resolved.

    Raises
    ------
    ParameterError
        One line naming ``--out``, what is wrong and what to do.
    """
    text = str(out)
    if text.strip() == "":
        raise _refuse(repr(text), "expected a folder name, got an empty one", suggest=False)
    target = Path(os.path.abspath(os.path.expanduser(text)))
    try:
        resolved = target.resolve()
    except (OSError, RuntimeError) as err:
        raise _refuse(text, f"cannot resolve the path ({err})", suggest=False) from None
    cwd = Path.cwd().resolve()
    home = Path.home().resolve()
    if resolved == Path(resolved.anchor) or resolved == home or _within(cwd, resolved):
        what = ("the root folder" if resolved == Path(resolved.anchor) else "your home folder" if resolved == home
                else "the current folder" if resolved == cwd else "a folder that contains the current folder")
        raise _refuse(text, f"is {what}; roadcollab writes its results into a folder of their own")
    for item in inputs:
        if item is None or str(item) in ("", "packaged") or not os.path.lexists(os.path.expanduser(str(item))):
            continue  # a missing input gets its own message from the option that names it
        p = Path(os.path.abspath(os.path.expanduser(str(item)))).resolve()
        if _within(p, resolved):
            raise _refuse(text, f"holds the input {item}; results must not be written over or beside the inputs")
    if resolved.exists() or resolved.is_symlink():
        if not resolved.is_dir():
            raise _refuse(text, "expected a folder, got an existing file", suggest=False)
        manifest = read_manifest(resolved)
        if manifest is not None and manifest["command"] != command:
            raise _refuse(text, f"holds the results of 'roadcollab {manifest['command']}', not of '{command}'")
        foreign = _foreign(resolved, manifest)
        if foreign and manifest is None:
            more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
            raise _refuse(text, f"is not empty and has no roadcollab manifest ({MANIFEST}): it holds "
                                f"{foreign[0]!r}{more}; roadcollab writes only into an absent or empty folder or "
                                f"a previous result of the same command (a result of an older roadcollab: remove "
                                f"it yourself or pick another folder)", suggest=False)
        if not os.access(resolved, os.W_OK | os.X_OK):
            raise _refuse(text, "is not writable", suggest=False)
    else:
        parent = resolved.parent
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            raise _refuse(text, f"cannot be created ({parent} is not a writable folder)", suggest=False)
    return resolved


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_leftovers(out: Path) -> None:
    """Remove staging folders of killed runs beside ``out``: only those with our mark and a dead pid."""
    if not out.parent.is_dir():
        return
    for d in out.parent.glob(f".{out.name}.partial-*"):
        try:
            pid = int(json.loads((d / STAGING_MARK).read_text())["pid"])
        except (OSError, ValueError, KeyError, TypeError):
            continue  # not ours: never touched
        if d.is_dir() and not d.is_symlink() and not _pid_alive(pid):
            shutil.rmtree(d, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _staging(out: Path, kind: str) -> Path:
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.{kind}-", dir=out.parent))
        tmp.chmod(0o777 & ~_umask())  # mkdtemp makes 0700; the results get the usual permissions
        (tmp / STAGING_MARK).write_text(json.dumps({"pid": os.getpid()}))
        return tmp
    except OSError as err:
        raise _refuse(out, f"cannot write there ({err.strerror or err})", suggest=False) from None


def _written(tmp: Path) -> list[str]:
    """The files a run wrote into its staging folder (relative, sorted), marks excluded."""
    return sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*")
                  if p.is_file() and p.name not in (STAGING_MARK, MANIFEST))


def _commit(tmp: Path, out: Path, command: str) -> None:
    """Move the staged files into ``out``: a rename of the folder when ``out`` is absent, otherwise
    file by file, replacing only what the previous manifest lists."""
    files = _written(tmp)
    manifest = {"roadcollab": __version__, "command": command, "files": files}
    (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    (tmp / STAGING_MARK).unlink()
    if not out.exists():
        os.replace(tmp, out)
        return
    previous = read_manifest(out)
    if previous is not None and previous["command"] != command:
        raise _refuse(out, f"now holds the results of 'roadcollab {previous['command']}' (written while this "
                           f"run computed); the new results are in {tmp}", suggest=False)
    new = set(files)
    for f in files:
        dest = out / f
        dest.parent.mkdir(parents=True, exist_ok=True)
        if dest.is_dir() and not dest.is_symlink():
            raise _refuse(out, f"{f} is a folder there now; the new results are in {tmp}", suggest=False)
        os.replace(tmp / f, dest)
    for f in (previous or {"files": []})["files"]:  # our old files the new run did not write again
        p = out / f
        if f not in new and not os.path.isabs(f) and ".." not in Path(f).parts and (p.is_file() or p.is_symlink()):
            p.unlink()
    os.replace(tmp / MANIFEST, out / MANIFEST)
    shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def staged_output(out, command: str = "", inputs: Iterable = ()) -> Iterator[Path]:
    """Write a run's outputs into a staging folder beside ``out`` and move them in only at the end.

    Parameters
    ----------
    out : str or Path
        The result folder (:func:`check_output_folder` is applied on entry, before any compute).
    command : str
        The subcommand, recorded in the manifest.
    inputs : iterable
        The run's input files and folders (refused inside ``out``).

    Yields
    ------
    Path
        The staging folder to write into.

    Raises
    ------
    ParameterError
        ``out`` refused, or the results cannot be moved into place (they are kept in the staging folder).
    """
    out = check_output_folder(out, command, inputs)
    _remove_leftovers(out)
    tmp = _staging(out, "partial")
    try:
        yield tmp
        try:
            _commit(tmp, out, command)
        except OSError as err:
            raise _refuse(out, f"cannot move the results into place ({err.strerror or err}); they are in {tmp}",
                          suggest=False) from None
    except BaseException:
        if tmp.exists() and (tmp / STAGING_MARK).exists():
            with _signals_held():  # a second Ctrl-C must not leave half a staging folder without its mark
                shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def _signals_held():
    """Hold SIGINT and SIGTERM (delivered afterwards) while a cleanup runs, where the platform can."""
    held = {signal.SIGINT, signal.SIGTERM}
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def check_output_file(path, inputs: Iterable = (), *, is_ours=None) -> Path:
    """Refuse an ``--out`` file that is an input, a folder, or an existing file roadcollab did not write.

    Parameters
    ----------
    path : str or Path
    inputs : iterable
        Input files (refused as the output).
    is_ours : callable, optional
        ``is_ours(path) -> bool`` for an existing file (e.g. "is a roadcollab message"); without it an
        existing file is refused.

    Returns
    -------
    Path
    """
    text = str(path)
    if text.strip() == "":
        raise _refuse(repr(text), "expected a file name, got an empty one", suggest=False)
    p = Path(os.path.abspath(os.path.expanduser(text))).resolve()
    for item in inputs:
        if item is not None and Path(os.path.abspath(str(item))).resolve() == p:
            raise _refuse(text, "is an input of the run", suggest=False)
    if p.is_dir():
        raise _refuse(text, "expected a file, got an existing folder", suggest=False)
    if p.exists() and not (p.is_file() and is_ours is not None and is_ours(p)):
        raise ParameterError(f"--out {text}: the file exists and was not written by roadcollab; choose a new name")
    if not p.parent.is_dir() and p.parent.exists():
        raise _refuse(text, f"{p.parent} is not a folder", suggest=False)
    return p


@contextlib.contextmanager
def staged_file(path, inputs: Iterable = (), *, is_ours=None) -> Iterator[Path]:
    """Write one file under a temporary sibling name and rename it to ``path`` at the end.

    :func:`check_output_file` is applied on entry; a failed run leaves ``path`` untouched.

    Parameters
    ----------
    path : str or Path
    inputs : iterable
        Input files (refused as the output).
    is_ours : callable, optional
        As :func:`check_output_file`.

    Yields
    ------
    Path
        The temporary file to write.
    """
    path = check_output_file(path, inputs, is_ours=is_ours)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.partial-", dir=path.parent)
        os.close(fd)
        os.chmod(name, 0o666 & ~_umask())
    except OSError as err:
        raise _refuse(path, f"cannot write there ({err.strerror or err})", suggest=False) from None
    tmp = Path(name)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
