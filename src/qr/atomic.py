"""Write-then-rename so no reader ever sees a half-written output, and qr only removes what it wrote.

Temporaries carry the writer's identity (:func:`qr.procs.temp_prefix`) so a killed process's are removed
later; files and folders are ``fsync``-ed around the rename; an output folder's marker ``.qr-output.json``
lists the files qr wrote there, the only ones it replaces.  docs/cli.md "Your files are safe".
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from pathlib import Path, PurePosixPath
from typing import Iterator

from .errors import QrInputError
from .procs import is_temporary, signals_held, temp_prefix

MARKER = ".qr-output.json"


def _fsync(path: Path) -> None:
    """Flush a file, or a folder's entries, to the disk (a folder that cannot be fsync-ed is skipped)."""
    flags = os.O_RDONLY | (os.O_DIRECTORY if path.is_dir() else 0)
    try:
        fd = os.open(path, flags)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync on a folder (EINVAL): nothing to flush there
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(dest: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``dest``; rename it onto ``dest`` only on success."""
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=temp_prefix(dest.name), suffix=suffix or dest.suffix or ".tmp",
                               dir=dest.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; outputs are meant to be shared
    try:
        yield tmp_path
        _fsync(tmp_path)
        os.replace(tmp_path, dest)
        _fsync(dest.parent)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


# ---- output folders ------------------------------------------------------------------------------

def owned_files(folder: str | Path) -> list[str] | None:
    """The files qr wrote in ``folder`` (relative POSIX paths) per its marker; None: not a qr output."""
    try:
        doc = json.loads((Path(folder) / MARKER).read_text())
        files = doc["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if doc.get("tool") != "qr" or not isinstance(files, list):
        return None
    # only paths inside the folder: a damaged or hand-made marker must never point qr elsewhere
    return [f for f in files if isinstance(f, str) and f and not PurePosixPath(f).is_absolute()
            and ".." not in PurePosixPath(f).parts]


def user_entries(folder: str | Path) -> list[Path]:
    """What is in ``folder`` besides qr's marker and write-then-rename temporaries."""
    return sorted(p for p in Path(folder).iterdir() if p.name != MARKER and not is_temporary(p.name))


def in_the_way(folder: Path, rel: str, owned) -> bool:
    """Whether writing ``folder/rel`` would overwrite, or write through, something qr did not write."""
    parts = PurePosixPath(rel).parts
    for i in range(1, len(parts)):  # each parent must be a real folder (a symlink could lead anywhere)
        p = folder.joinpath(*parts[:i])
        if p.is_symlink() or (p.exists() and not p.is_dir()):
            return True
    p = folder / rel
    if not (p.exists() or p.is_symlink()):
        return False
    return rel not in owned or (p.is_dir() and not p.is_symlink())


def _write_marker(folder: Path, files, command: str) -> None:
    from . import __version__

    doc = {"tool": "qr", "command": command, "qr_version": __version__,
           "note": "qr wrote the files listed here and replaces exactly these when it writes this folder "
                   "again; any other file in this folder is left alone",
           "files": sorted(files)}
    with atomic_path(folder / MARKER) as tmp:
        tmp.write_text(json.dumps(doc, indent=2) + "\n")


def _files_under(root: Path) -> list[str]:
    out = []
    for dirpath, _, filenames in os.walk(root):
        for name in filenames:
            rel = (Path(dirpath) / name).relative_to(root).as_posix()
            if rel != MARKER:
                out.append(rel)
    return sorted(out)


def _fsync_tree(root: Path) -> None:
    for dirpath, _, filenames in os.walk(root):
        for name in filenames:
            _fsync(Path(dirpath) / name)
        _fsync(Path(dirpath))


def _refuse_foreign(dest: Path) -> None:
    raise QrInputError(dest, "the folder is not empty and is not a previous qr output (it has no "
                       f"{MARKER})", "give a new or empty folder for --out, or add --force to write qr's files "
                       "beside the ones there (none of them is replaced)")


@contextlib.contextmanager
def atomic_dir(dest: str | Path, force: bool = False, command: str = "qr") -> Iterator[Path]:
    """Yield a temporary folder; on success put its files at ``dest``, removing only what qr wrote.

    - ``dest`` missing: the temporary (beside it) is renamed into place, marker included.
    - ``dest`` empty or a previous qr output (its marker): the new files replace exactly the files the
      marker lists (a file qr wrote before and does not write now is removed); any other file stays.
      The temporary is built inside ``dest`` (same file system: every move is a rename), and the
      marker lists the old and the new files while they are moved, so ``dest`` is recognisably qr's
      at every moment, also after a crash.
    - ``dest`` non-empty and not qr's: refused, unless ``force``, which writes beside what is there.
    A file qr did not write is never replaced: one in the way is refused (:class:`QrInputError`),
    before any work when it is there from the start, at the end otherwise.
    """
    dest = Path(dest)
    if dest.exists() and not dest.is_dir():
        raise QrInputError(dest, "a file is in the way of the output folder", "give a folder for --out, or "
                           "move the file away")
    if dest.is_dir():
        if owned_files(dest) is None and user_entries(dest) and not force:
            _refuse_foreign(dest)
        base = dest
    else:
        dest.parent.mkdir(parents=True, exist_ok=True)
        base = dest.parent
    tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(dest.name), dir=base))
    os.chmod(tmp, 0o777 & ~_umask())
    try:
        yield tmp
        _fsync_tree(tmp)
        with signals_held():  # a SIGTERM now would leave a mix of old and new files
            _put_in_place(tmp, dest, force, command)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _put_in_place(tmp: Path, dest: Path, force: bool, command: str) -> None:
    files = _files_under(tmp)
    if not dest.exists() and tmp.parent != dest:
        _write_marker(tmp, files, command)
        try:
            os.replace(tmp, dest)
            _fsync(dest.parent)
            return
        except OSError:  # dest appeared meanwhile: go on as for an existing folder
            (tmp / MARKER).unlink(missing_ok=True)
    if not dest.is_dir():
        raise QrInputError(dest, "a file is in the way of the output folder", "give a folder for --out, or "
                           "move the file away")
    old = owned_files(dest)
    if old is None:
        if [p for p in user_entries(dest) if p != tmp] and not force:
            _refuse_foreign(dest)
        old = []
    clash = [rel for rel in files if in_the_way(dest, rel, old)]
    if clash:
        raise QrInputError(dest / clash[0], "qr did not write this file and would have to replace it "
                           f"({len(clash)} such file(s))", "move it away, or give another --out")
    _write_marker(dest, set(old) | set(files), command)
    for rel in files:
        target = dest / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / rel, target)
    for rel in set(old) - set(files):  # qr's own files of the previous output
        stale = dest / rel
        if stale.is_symlink() or stale.is_file():
            stale.unlink()
    for d in {(dest / rel).parent for rel in set(old) | set(files)}:
        _fsync(d)
    _write_marker(dest, files, command)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# ---- text and JSON -------------------------------------------------------------------------------

def write_text(dest: str | Path, text: str) -> None:
    write_file(dest, text)


def write_file(dest: str | Path, data: str | bytes) -> None:
    """Text or bytes; the folders up to it made."""
    with atomic_path(dest) as tmp:
        tmp.write_text(data) if isinstance(data, str) else tmp.write_bytes(data)


def plain(x):
    """``x`` with numpy arrays and scalars as Python lists and numbers (for JSON and YAML writers)."""
    import numpy as np

    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def finite_or_null(obj, path: str = "") -> tuple[object, list[str]]:
    """``obj`` with every non-finite float (NaN, ±inf) replaced by None, and the dotted paths replaced."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None, [path]
    if isinstance(obj, dict):
        out, where = {}, []
        for k, v in obj.items():
            out[k], w = finite_or_null(v, f"{path}.{k}" if path else str(k))
            where += w
        return out, where
    if isinstance(obj, (list, tuple)):
        out, where = [], []
        for i, v in enumerate(obj):
            x, w = finite_or_null(v, f"{path}[{i}]")
            out.append(x)
            where += w
        return out, where
    return obj, []


def write_json(dest: str | Path, obj) -> None:
    """Strict JSON (RFC 8259): a number that is not finite is written as null."""
    write_text(dest, json.dumps(finite_or_null(obj)[0], indent=2, sort_keys=False, allow_nan=False) + "\n")
