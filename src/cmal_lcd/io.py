"""Atomic writes: a reader never sees a half-written file, nor a half-replaced folder. And one
check before reading a user's file: :func:`check_regular_file`.

Files: every stage writes through :func:`atomic_path` and the ``atomic_write_*`` helpers: the
content goes to a temporary file in the same folder, is flushed to disk, then renamed over the
target (``os.replace`` is atomic on POSIX). A process killed mid-write leaves at most a stray
``.tmp-*`` file, never a truncated output.

Folders (old or new, never a mix or nothing; docs/reliability.md, "Old or new outputs"):

- :func:`staged_folder`: a whole output folder is written into ``.<name>.new-<id>`` beside it,
  then swapped in (old renamed to ``.<name>.old-<id>``, new renamed in, old deleted; on an
  error the old one renamed back). A kill leaves ``.<name>.new-<id>`` (and, between the two
  renames, ``.<name>.old-<id>`` with no ``<name>``): :func:`recover_folder`, which the next
  write of the same folder calls first, renames a complete new one in and deletes the rest.
  The writer holds an exclusive ``flock`` on its staging folder until the swap is done, so
  recovery never touches the folder of a writer still running (the kernel drops the lock of
  a killed one).
- :func:`staged_entries`: several entries of a folder that also holds entries of others
  (``reports/``: the report's README, tables, figures... beside ``reports/world`` and
  ``reports/seeds``) are written into ``.<tag>.new-<id>`` inside it. The commit point is a
  manifest written atomically into that folder once it is complete; then each entry is
  swapped in turn. No single rename can replace several siblings, so a kill *inside* those
  few renames (after the commit point) leaves a mix until :func:`recover_entries`, which the
  next run calls before anything else, finishes the swap from the manifest (roll forward).
  A kill before the commit point leaves the previous entries untouched; after the last
  rename, the new ones.
"""

from __future__ import annotations

import contextlib
import errno
import fnmatch
import glob
import json
import logging
import math
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator, Sequence

import numpy as np

try:
    import fcntl
except ImportError:  # not POSIX: staging folders are not locked, leftovers are kept
    fcntl = None  # type: ignore[assignment]

logger = logging.getLogger(__name__)


class NotRegularFileError(ValueError):
    """An input path is a FIFO, a device, a socket or a folder: reading it could block forever
    or never end (``/dev/zero``), so it is refused before it is opened."""


def check_regular_file(path: str | os.PathLike, *, what: str = "file") -> None:
    """Refuse ``path`` unless it is (a link to) a regular file; a missing path passes (the
    reader names it). ``os.stat`` does not open the file, so a FIFO cannot block it.

    Raises
    ------
    NotRegularFileError
        ``<path>: not a regular file (a FIFO); <what> must be a file``.
    """
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if stat.S_ISREG(mode):
        return
    kind = ("a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else
            "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "not a plain file")
    raise NotRegularFileError(f"{path}: not a regular file ({kind}); {what} must be a file")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it to ``path``.

    On an exception the temporary file is removed and ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".tmp-{path.name}.", suffix=path.suffix)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; outputs get the usual mode
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp_path, path)
    except BaseException as err:
        tmp_path.unlink(missing_ok=True)
        _raise_if_full(err, path, kept="the previous file is kept")
        raise


#: ``OSError.errno`` values of a full device or an exhausted quota.
_FULL = (errno.ENOSPC, errno.EDQUOT)


class DiskFullError(OSError):
    """An output could not be written: its device is full (or the quota spent). Its message
    names the output; ``errno`` is the original one."""


def _raise_if_full(err: BaseException, where: str | os.PathLike, *, kept: str) -> None:
    """A write that filled the device (``[Errno 28]``, which names no file) becomes a
    :class:`DiskFullError` naming ``where``, the output being written (the outermost one, when
    a file of a staged folder filled it)."""
    cause = err.__cause__ if isinstance(err, DiskFullError) else err
    if isinstance(cause, OSError) and cause.errno in _FULL:
        full = DiskFullError(f"{where}: no space left on the device to write it "
                             f"({cause.strerror}); {kept}, and nothing half-written is left")
        full.errno = cause.errno
        raise full from cause


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def _json_safe(value: Any) -> Any:
    """Replace NaN/inf (not valid JSON) by ``None`` and numpy scalars by Python ones."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_safe(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as indented, key-sorted JSON; NaN and inf become ``null``."""
    text = json.dumps(_json_safe(obj), indent=2, sort_keys=True, allow_nan=False)
    return atomic_write_text(path, text + "\n")


def atomic_save_npy(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Save ``array`` in ``.npy`` format atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.save(fh, array, allow_pickle=False)
    return Path(path)


def atomic_save_npz(path: str | os.PathLike, **arrays: np.ndarray) -> Path:
    """Save named arrays as a compressed ``.npz`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    return Path(path)


# ---------------------------------------------------------------------------- folders

#: The commit point of :func:`staged_entries`: written last into the staging folder.
MANIFEST = ".staged-entries.json"


def _fsync_dir(folder: Path) -> None:
    """Flush ``folder``'s entries (renames) to disk; a no-op where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _remove(path: Path) -> None:
    """Delete a file, link or folder (a missing one is fine)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _sibling(staging: Path, kind: str) -> Path:
    """``.<name>.old-<id>`` for the staging folder ``.<name>.new-<id>``."""
    head, _, ident = staging.name.rpartition(".new-")
    return staging.parent / f"{head}.{kind}-{ident}"


@contextlib.contextmanager
def staged_folder(out_dir: str | os.PathLike, *, recover: bool = True) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``out_dir``; on success it replaces ``out_dir``.

    The old ``out_dir`` (if any) is renamed aside, the new one renamed in, the old one deleted:
    an exception at any point leaves the previous complete folder (or none) and no temporary
    folder; a SIGKILL leaves the previous folder plus ``.<name>.new-*`` beside it (or, between
    the two renames, both halves: see :func:`recover_folder`), which the next write of
    ``out_dir`` recovers first. The staging folder stays locked (``flock``) while this runs.

    Parameters
    ----------
    recover : bool
        First finish or clean up what a killed earlier write of ``out_dir`` left beside it
        (:func:`recover_folder`; the default). Staging folders of writers still running are
        locked and left alone, so several writers may share a parent folder, even an output.

    Raises
    ------
    ValueError
        Naming ``out_dir`` when its parent cannot take a new folder (before any work is done).
    """
    out_dir = Path(out_dir)
    target = Path(os.path.realpath(out_dir))  # a symbolic link's target folder is replaced
    if recover:
        recover_folder(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        staging, lock = _new_staging_folder(target)
    except OSError as err:
        raise ValueError(f"{out_dir}: cannot create the output folder "
                         f"({err.strerror or err})") from err
    try:
        yield staging
        swap_in_folder(staging, target)
    except BaseException as err:
        shutil.rmtree(staging, ignore_errors=True)
        _raise_if_full(err, out_dir, kept="the previous outputs are kept")
        raise
    finally:
        if lock is not None:
            os.close(lock)


def swap_in_folder(staging: Path, target: Path) -> None:
    """Rename ``staging`` to ``target``, the old ``target`` aside first and deleted last."""
    os.chmod(staging, 0o777 & ~_umask())  # mkdtemp creates 0700
    if not os.path.lexists(target):
        os.rename(staging, target)
        _fsync_dir(target.parent)
        return
    old = _sibling(staging, "old")
    os.rename(target, old)
    try:
        os.rename(staging, target)
    except BaseException:
        os.rename(old, target)
        raise
    _fsync_dir(target.parent)
    shutil.rmtree(old, ignore_errors=True)


#: ``.<name>.new-<id>`` / ``.<name>.old-<id>`` of :func:`staged_folder` (``mkdtemp``'s ids
#: hold no dot, so the staging folders of an output named ``<name>.new-x`` never match).
_STAGING = r"\.{name}\.(?P<kind>new|old)-[^./]+"
_LOCK_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0)


def _lock_folder(folder: Path) -> int | None:
    """An open descriptor of ``folder`` holding an exclusive ``flock`` on it; ``None`` when
    another process holds the lock or ``folder`` is gone (or is no longer a plain folder).

    Raises
    ------
    OSError
        When folders cannot be locked here (no ``fcntl``, a file system without locks).
    """
    try:
        fd = os.open(folder, _LOCK_FLAGS)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as err:
        if err.errno == errno.ELOOP:  # became a symbolic link
            return None
        raise
    try:
        if fcntl is None:
            raise OSError(f"{folder}: file locks are not available on this platform")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        try:
            same = os.path.samestat(os.fstat(fd), os.lstat(folder))
        except FileNotFoundError:
            same = False
        if not same:  # deleted (or replaced) between the open and the lock
            os.close(fd)
            return None
    except BaseException:
        with contextlib.suppress(OSError):
            os.close(fd)
        raise
    return fd


def _new_staging_folder(target: Path) -> tuple[Path, int | None]:
    """A new, empty ``.<name>.new-<id>`` beside ``target`` and the descriptor locking it
    (``None`` where folders cannot be locked)."""
    for _ in range(100):
        staging = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{target.name}.new-"))
        try:
            lock = _lock_folder(staging)
        except OSError as err:
            logger.debug("%s: staging folder not locked (%s)", staging, err)
            return staging, None
        if lock is not None:
            return staging, lock
        # another writer's recovery took it for a leftover in the instant before it was
        # locked (and is deleting it): take another one
    raise OSError(f"{target.parent}: could not lock a new staging folder for {target.name}")


def _leftovers(target: Path) -> dict[str, list[Path]]:
    """``{"new": [...], "old": [...]}``: the folders beside ``target`` named as
    :func:`staged_folder` names its temporary ones (files and symbolic links excluded)."""
    pattern = re.compile(_STAGING.format(name=re.escape(target.name)))
    found: dict[str, list[Path]] = {"new": [], "old": []}
    with os.scandir(target.parent) as entries:
        for entry in entries:
            match = pattern.fullmatch(entry.name)
            if match and entry.is_dir(follow_symlinks=False):
                found[match["kind"]].append(Path(entry.path))
    return {kind: sorted(paths) for kind, paths in found.items()}


def _remove_leftover(folder: Path, target: Path) -> None:
    shutil.rmtree(folder, ignore_errors=True)  # never follows symbolic links inside
    if os.path.lexists(folder):
        logger.warning("could not remove %s, left by an interrupted write of %s", folder,
                       target)
    else:
        logger.info("removed %s, left by an interrupted write of %s", folder, target)


def recover_folder(target: str | os.PathLike) -> None:
    """Finish or undo a swap of :func:`staged_folder` that a kill interrupted.

    ``.<name>.new-<id>`` with its ``.<name>.old-<id>`` and no ``<name>``: the kill fell between
    the two renames, so the new folder is complete and is renamed in. Any other
    ``.<name>.new-*`` (an unfinished write) and ``.<name>.old-*`` (a swap that only had the
    deletion left) is deleted, one INFO log line each. Only folders beside ``target`` with
    exactly those names are touched (no symbolic link is followed), and never one a running
    writer holds locked (nor the ``.old-<id>`` of its ``.new-<id>``).
    """
    target = Path(target)
    if not target.parent.is_dir():
        return
    leftovers = _leftovers(target)
    for staging in leftovers["new"]:
        try:
            lock = _lock_folder(staging)
        except OSError as err:
            logger.info("kept %s: cannot tell whether a running write of %s owns it (%s)",
                        staging, target, err)
            continue
        if lock is None:
            continue  # a running writer's (or gone)
        try:
            old = _sibling(staging, "old")
            if old in leftovers["old"] and not os.path.lexists(target):
                os.rename(staging, target)
                logger.info("renamed %s to %s: a killed write had swapped it halfway",
                            staging, target)
            else:
                _remove_leftover(staging, target)
        finally:
            os.close(lock)
    for old in leftovers["old"]:
        head, _, ident = old.name.rpartition(".old-")
        if os.path.lexists(old.parent / f"{head}.new-{ident}"):
            continue  # its writer is between its two renames (its .new- is locked)
        _remove_leftover(old, target)


@contextlib.contextmanager
def staged_entries(parent: str | os.PathLike, names: Sequence[str], *,
                   tag: str) -> Iterator[Path]:
    """Yield an empty temporary folder inside ``parent``; on success, what it holds replaces
    the entries ``names`` of ``parent`` together (one of ``names`` it lacks is removed).

    Entries of ``parent`` outside ``names`` are never touched. What an earlier, killed run
    left (``.<tag>.new-*``, ``.<tag>.old-*``) is recovered first (:func:`recover_entries`).
    On an exception the previous entries are put back and no temporary folder is left.

    Raises
    ------
    ValueError
        When the staging folder holds an entry outside ``names`` (before anything is swapped).
    """
    parent = Path(parent)
    names = list(names)
    recover_entries(parent, tag=tag)
    parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=parent, prefix=f".{tag}.new-"))
    try:
        yield staging
        swap_in_entries(staging, parent, names)
    except BaseException as err:
        if not (staging / MANIFEST).exists():  # else a failed roll-back: recovery's to finish
            shutil.rmtree(staging, ignore_errors=True)
        _raise_if_full(err, parent, kept="the previous outputs are kept")
        raise


def swap_in_entries(staging: Path, parent: Path, names: Sequence[str]) -> None:
    """Commit ``staging`` (its manifest), then replace ``parent``'s ``names`` by its entries.

    An exception while swapping moves the previous entries back (then re-raises); if that
    fails too, the manifest stays and :func:`recover_entries` rolls forward later.
    """
    produced = sorted(p.name for p in staging.iterdir() if p.name != MANIFEST)
    foreign = [name for name in produced if name not in names]
    if foreign:
        raise ValueError(f"{staging}: {foreign[0]!r} is not one of the entries this writer "
                         f"replaces ({', '.join(names)})")
    atomic_write_json(staging / MANIFEST, {"replaces": list(names), "produced": produced})
    try:
        _roll_forward(staging)
    except BaseException:
        _roll_back(staging)
        raise


def _read_manifest(staging: Path) -> tuple[list[str], set[str]]:
    manifest = json.loads((staging / MANIFEST).read_text(encoding="utf-8"))
    return list(manifest["replaces"]), set(manifest["produced"])


def _roll_forward(staging: Path) -> None:
    """Swap every entry of a committed staging folder in; each step checks where it stands,
    so running it again after a kill finishes the job."""
    parent, old = staging.parent, _sibling(staging, "old")
    names, produced = _read_manifest(staging)
    old.mkdir(exist_ok=True)
    for name in names:
        target, new = parent / name, staging / name
        if name in produced and not os.path.lexists(new):
            continue  # swapped in already
        if os.path.lexists(target):
            aside = old / name
            if os.path.lexists(aside):  # not written by this process: keep the older one
                _remove(target)
            else:
                os.rename(target, aside)
        if name in produced:
            os.rename(new, target)
    _fsync_dir(parent)
    shutil.rmtree(old, ignore_errors=True)
    shutil.rmtree(staging, ignore_errors=True)


def _roll_back(staging: Path) -> None:
    """Undo a partial :func:`_roll_forward`: the new entries back into ``staging``, the old
    ones back into place; then both temporary folders deleted. Errors are left to recovery."""
    parent, old = staging.parent, _sibling(staging, "old")
    try:
        names, produced = _read_manifest(staging)
        for name in names:
            target = parent / name
            if name in produced and not os.path.lexists(staging / name) \
                    and os.path.lexists(target):
                os.rename(target, staging / name)
            if os.path.lexists(old / name):
                os.rename(old / name, target)
        (staging / MANIFEST).unlink()
    except OSError:
        return
    shutil.rmtree(old, ignore_errors=True)
    shutil.rmtree(staging, ignore_errors=True)


def recover_entries(parent: str | os.PathLike, *, tag: str) -> None:
    """Finish what a killed :func:`staged_entries` left in ``parent``.

    A ``.<tag>.new-*`` folder holding its manifest was complete: its swap is finished (roll
    forward). One without (an unfinished write) and any ``.<tag>.old-*`` left after a finished
    swap are deleted.
    """
    parent = Path(parent)
    if not parent.is_dir():
        return
    for staging in sorted(parent.glob(f".{glob.escape(tag)}.new-*")):
        if (staging / MANIFEST).is_file():
            _roll_forward(staging)
        else:
            shutil.rmtree(staging, ignore_errors=True)
    for old in sorted(parent.glob(f".{glob.escape(tag)}.old-*")):
        shutil.rmtree(old, ignore_errors=True)


# ------------------------------------------------------------------ a command's output folder

def check_output_folder(out_dir: str | os.PathLike, files: Sequence[str], *,
                        command: str) -> None:
    """Refuse an ``--out`` that is a file, or holds anything but ``files``: the names
    ``command`` writes, each a name or a glob pattern (``table2_*.csv``) of one file, or of one
    folder when it ends with ``/`` (``jobs/``).

    Raises
    ------
    ValueError
        Naming ``out_dir`` (a file in the way, a foreign entry) or the output file a folder
        stands in the way of. Nothing is changed.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"{out_dir}: --out is a file, not a folder")
    if not out_dir.is_dir():
        return
    entries = sorted(os.listdir(out_dir))
    for name in entries:
        patterns = [p for p in files if fnmatch.fnmatchcase(name, p.rstrip("/"))]
        if patterns and all(not p.endswith("/") for p in patterns) and (out_dir / name).is_dir():
            raise ValueError(f"{out_dir / name}: a folder stands where this output file goes; "
                             f"move it or choose another --out")
    foreign = [name for name in entries
               if not any(fnmatch.fnmatchcase(name, p.rstrip("/")) for p in files)]
    if foreign:
        what = "an entry" if len(foreign) == 1 else f"{len(foreign)} entries"
        raise ValueError(f"{out_dir}: --out holds {what} {command} did not write (first "
                         f"{foreign[0]!r}); {command} replaces the whole folder, so choose a "
                         f"new or empty --out (nothing was changed)")


def check_output_apart(out_dir: str | os.PathLike, inputs: Sequence[str | os.PathLike]) -> None:
    """Refuse an ``--out`` that is the working directory (replacing it would pull the folder
    out from under the shell), or an input, or lies inside or around one (the next read of
    that input would list the outputs) (issue 38 item 12).

    Raises
    ------
    ValueError
        Naming ``--out`` and the input.
    """
    out = Path(out_dir).resolve()
    if out == Path.cwd().resolve():
        raise ValueError(f"--out {out_dir}: the working directory; the output folder is "
                         f"replaced as a whole, so give a folder of its own")
    for given in inputs:
        source = Path(given).resolve()
        if out == source or source in out.parents or out in source.parents:
            raise ValueError(f"--out {out_dir}: inside or around the input {given}; give a "
                             f"folder apart from the inputs")


@contextlib.contextmanager
def staged_output_folder(out_dir: str | os.PathLike, files: Sequence[str], *, command: str,
                         inputs: Sequence[str | os.PathLike] = ()) -> Iterator[Path]:
    """A command's output folder, old or new: yield an empty temporary folder beside
    ``out_dir``; on success it replaces ``out_dir`` (which may hold only ``files``, what
    ``command`` writes, and may be neither the working directory nor one of the ``inputs`` or
    a folder inside or around one). ``match``, ``loops``, ``aggregate`` and ``seeds-report``
    write through it.

    :func:`staged_folder` after :func:`check_output_folder`: the old ``out_dir`` (if any) is
    renamed aside, the new one renamed in, the old one deleted: a failure at any point leaves
    the previous complete outputs (or none), never a mix, and no temporary folder (except after
    a hard kill, which leaves ``.<name>.new-*`` beside it until the next write of the same
    ``out_dir`` removes it). Outputs of an earlier run that this one does not write are gone
    afterwards, so a folder never mixes two runs.

    Raises
    ------
    ValueError
        From :func:`check_output_folder` or :func:`check_output_apart`, or naming ``out_dir``
        when its parent cannot take a new folder (before any work is done).
    """
    check_output_folder(out_dir, files, command=command)
    check_output_apart(out_dir, inputs)
    with staged_folder(out_dir) as staging:
        yield staging
