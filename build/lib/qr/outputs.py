"""Where a command may write: its ``--out`` checked before any work, and the leftovers of killed runs.

The rule: qr only ever removes or replaces what it wrote itself.  An output
folder is new, empty, or a previous qr output (its marker,
:data:`qr.atomic.MARKER`); a non-empty folder of the user's takes ``--force``,
and even then no file of the user's is replaced.  An output file is new, or
``--force`` replaces it.  Never allowed: the current folder, a folder that
contains an input, an output file that is an input.  Every refusal is one
:class:`qr.errors.QrInputError` line, raised before anything is read or written.
"""

from __future__ import annotations

import os
from pathlib import Path

from .atomic import in_the_way, owned_files, user_entries
from .errors import QrInputError
from .procs import remove_orphan_temporaries


def _writable(folder: Path) -> bool:
    return os.access(folder, os.W_OK | os.X_OK)


def _check_parent(out: Path, where: Path) -> None:
    parent = where.parent
    if not parent.is_dir():
        what = "is not a folder" if parent.exists() else "does not exist"
        raise QrInputError(out, f"the folder it would go in, {parent}, {what}", f"create {parent} first, or give "
                           "another --out")
    if not _writable(parent):
        raise QrInputError(out, f"the folder it would go in, {parent}, is not writable", "give an --out in a "
                           "folder you can write to")


def _check_not_holding_inputs(out: Path, where: Path, inputs) -> None:
    cwd = Path.cwd().resolve()
    if where == cwd or where in cwd.parents:
        raise QrInputError(out, "--out is the current folder (or holds it); qr writes its outputs in a folder of "
                           "their own", "give a new folder, e.g. --out diag")
    for f in inputs:
        if f is None or not isinstance(f, (str, os.PathLike)):
            continue
        r = Path(f).resolve()
        if where == r:
            raise QrInputError(out, "--out is an input of this command", "give another --out; qr never "
                               "overwrites its input")
        if where in r.parents:
            raise QrInputError(out, f"--out holds the input {f}", "give an output folder that holds none of the "
                               "inputs (e.g. a new folder beside them)")


def check_out_dir(out, inputs=(), force: bool = False, expected=()) -> Path:
    """Refuse an unusable output folder before any work; then remove temporaries of killed runs there.

    ``expected``: the paths (relative to ``out``) the command will write, checked against files of the
    user's that are in the way; a name ending in ``/`` is a folder.
    """
    out = Path(out)
    where = out.resolve()
    _check_not_holding_inputs(out, where, inputs)
    if out.exists() and not out.is_dir():
        raise QrInputError(out, "a file is in the way of the output folder", "give a new folder for --out, or "
                           "move the file away")
    if not out.exists():
        _check_parent(out, where)
    else:
        if not _writable(out):
            raise QrInputError(out, "the output folder is not writable", "give an --out you can write to")
        owned = owned_files(out)
        if owned is None and user_entries(out) and not force:
            n = len(user_entries(out))
            raise QrInputError(out, f"the folder is not empty ({n} entr{'y' if n == 1 else 'ies'}) and is not a "
                               "previous qr output", "give a new or empty folder for --out, or add --force to "
                               "write qr's files beside the ones there (none of them is replaced)")
        for rel in expected:
            if rel.endswith("/"):
                p = out / rel.rstrip("/")
                if p.is_symlink() or (p.exists() and not p.is_dir()):
                    raise QrInputError(p, "qr writes a folder of this name and a file is in the way",
                                       "move it away, or give another --out")
            elif in_the_way(out, rel, owned or []):
                raise QrInputError(out / rel, "qr would have to replace this file, which it did not write",
                                   "move it away, or give another --out")
        remove_orphan_temporaries(out, recursive=False)
    remove_orphan_temporaries(where.parent, recursive=False)
    return out


def check_out_file(out, inputs=(), force: bool = False) -> Path:
    """Refuse an unusable output file before any work (an existing one only with ``force``)."""
    out = Path(out)
    where = out.resolve()
    for f in inputs:
        if f is not None and isinstance(f, (str, os.PathLike)) and Path(f).resolve() == where:
            raise QrInputError(out, "--out is an input of this command", "give another --out; qr never "
                               "overwrites its input")
    if out.is_dir():
        raise QrInputError(out, "a folder is in the way of the output file", "give a file name for --out")
    _check_parent(out, where)
    if (out.exists() or out.is_symlink()) and not force:
        raise QrInputError(out, "the file exists", "give a new file name, or add --force to replace it")
    remove_orphan_temporaries(where.parent, recursive=False)
    return out
