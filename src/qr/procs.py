"""Who wrote this, and is that process still alive?  Clean-up after a killed run.

What a SIGKILLed process left (MLflow runs left RUNNING: :func:`qr.tracking.reap_stale`; :mod:`qr.atomic`'s
temporaries: :func:`remove_orphan_temporaries`) is recognised by its host, pid and start time and cleaned up
only when its owner is certainly gone (never another host's); :func:`sigterm_raises` and
:func:`signals_held` for SIGTERM and SIGINT.  docs/workflow.md "Interrupting and resuming".
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import socket
import sys
import threading
from pathlib import Path
from typing import Iterator

_HOST = None


def host() -> str:
    global _HOST
    if _HOST is None:
        # no dots or dashes: the name is one field of temporary and owner file names
        _HOST = re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname()) or "host"
    return _HOST


def start_time(pid: int) -> str | None:
    """The process's start time (clock ticks since boot, ``/proc/<pid>/stat`` field 22); None if unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) "
    return fields[19] if len(fields) > 19 else None


def _zombie(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2:].split()[0] in ("Z", "X")


def identity(pid: int | None = None) -> dict:
    """``{host, pid, start}`` of this process (or of ``pid`` on this host)."""
    pid = os.getpid() if pid is None else int(pid)
    return {"host": host(), "pid": pid, "start": start_time(pid) or ""}


def alive(pid, start: str | None = None, on_host: str | None = None) -> bool:
    """Whether the process is (possibly) still running.  Conservative: True unless certainly gone.

    A process on another host, or one we may not signal, counts as alive.  A zombie
    (killed, not yet reaped by its parent) counts as gone.
    """
    if on_host is not None and on_host != host():
        return True
    try:
        pid = int(pid)
    except (TypeError, ValueError):
        return True
    if pid <= 0:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    if _zombie(pid):
        return False
    now = start_time(pid)
    if start and now is not None and now != str(start):
        return False  # the pid was reused by a younger process
    return True


# ---- signals: SIGTERM as an exception, signals held back -----------------------------------------

class Terminated(KeyboardInterrupt):
    """SIGTERM, raised as an exception (:func:`sigterm_raises`) so that clean-up code runs."""


def _raise_terminated(signum, frame):
    raise Terminated(f"terminated by signal {signum}")


def _redeliver_swallowed(unraisable) -> None:
    """``sys.unraisablehook`` within :func:`sigterm_raises`.  An interrupt that lands in a finalizer or a weakref
    callback (SQLAlchemy has many) is printed and dropped by Python, and the job would go on as if
    never interrupted; the signal is sent again a moment later (from a timer thread: sent from here it
    would be raised here again), until it lands outside a finalizer."""
    exc = unraisable.exc_type
    if exc is not None and issubclass(exc, KeyboardInterrupt):
        sig = signal.SIGTERM if issubclass(exc, Terminated) else signal.SIGINT
        timer = threading.Timer(0.1, os.kill, (os.getpid(), sig))
        timer.daemon = True
        timer.start()
    (_previous_hook or sys.__unraisablehook__)(unraisable)


_previous_hook = None


def interrupt_in(e: BaseException | None):
    """The KeyboardInterrupt (or :class:`Terminated`) that ``e`` is, or was raised while handling, if any:
    an interrupt that lands while a compiled (numba) function is called comes back wrapped in a
    ``SystemError`` ("returned a result with an exception set")."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """Within, SIGTERM raises :class:`Terminated` in the main thread instead of ending the process on
    the spot, so clean-up code runs (a tracked run's status is written, temporaries are removed).
    Only the default action is replaced: a handler installed by someone else (submitit's, say) is
    left alone."""
    global _previous_hook
    installed = hooked = False
    if threading.current_thread() is threading.main_thread():
        try:
            if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
                signal.signal(signal.SIGTERM, _raise_terminated)
                installed = True
        except (ValueError, OSError):
            pass
        if sys.unraisablehook is not _redeliver_swallowed:
            _previous_hook, sys.unraisablehook = sys.unraisablehook, _redeliver_swallowed
            hooked = True
    try:
        yield
    finally:
        if installed and signal.getsignal(signal.SIGTERM) is _raise_terminated:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        if hooked and sys.unraisablehook is _redeliver_swallowed:
            sys.unraisablehook, _previous_hook = _previous_hook, None


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM wait (and are delivered afterwards) while something must not be cut short
    (a run's final status, the moves that put an output in place).

    Masking the signals is not enough: the kernel then hands a process-directed signal to another thread
    (numba's, torch's, a timer's), and Python runs its handler in the main thread at once, inside the block.
    So in the main thread the handlers themselves are swapped for one that notes the signal, and the first
    noted signal is raised again after the block, to the handler that was there before."""
    held = (signal.SIGINT, signal.SIGTERM)
    pending: list[int] = []
    swapped = {}
    if threading.current_thread() is threading.main_thread():
        for sig in held:
            if signal.getsignal(sig) is not None:  # None: a handler not set from Python, left as it is
                swapped[sig] = signal.signal(sig, lambda signum, frame: pending.append(signum))
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, set(held))
    except (AttributeError, ValueError, OSError):
        old = None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        for sig, handler in swapped.items():
            signal.signal(sig, handler)
        if pending:
            signal.raise_signal(pending[0])


# ---- write-then-rename temporaries ---------------------------------------------------------

TEMP_TAG = "qrtmp"
_TEMP_RE = re.compile(rf"^\..+\.{TEMP_TAG}-(?P<host>[A-Za-z0-9_]+)-(?P<pid>\d+)-(?P<start>\d*)\.")


def temp_prefix(name: str) -> str:
    """Prefix of a temporary beside output ``name``: hidden, and naming its writer."""
    me = identity()
    return f".{name}.{TEMP_TAG}-{me['host']}-{me['pid']}-{me['start']}."


def is_temporary(name: str) -> bool:
    """Whether ``name`` is a write-then-rename temporary of :mod:`qr.atomic` (any writer)."""
    return _TEMP_RE.match(name) is not None


def remove_orphan_temporaries(root, recursive: bool = True) -> list[Path]:
    """Remove temporaries under ``root`` whose writer (on this host) is gone; returns what was removed.

    ``recursive=False``: only ``root``'s own entries (what a command checks beside and inside its
    ``--out``, cheap even when ``root`` is a large folder).
    """
    removed = []
    root = Path(root)
    if not root.is_dir():
        return removed
    for dirpath, dirnames, filenames in os.walk(root):
        for name in list(dirnames) + filenames:
            m = _TEMP_RE.match(name)
            if not m or m["host"] != host() or alive(m["pid"], m["start"]):
                continue
            p = Path(dirpath) / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
                if name in dirnames:
                    dirnames.remove(name)
            else:
                p.unlink(missing_ok=True)
            removed.append(p)
        if not recursive:
            break
    return removed
