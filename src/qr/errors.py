"""User-facing errors: one line naming the file, the problem and the fix."""

from __future__ import annotations

import contextlib
import sys
import traceback
import warnings
from pathlib import Path
from typing import IO, Iterator

EXIT_BAD_INPUT = 2


class QrInputError(Exception):
    """Unusable user input. ``str(err)`` is the one line the user sees."""

    def __init__(self, path: str | Path | None, problem: str, fix: str):
        self.path = str(path) if path is not None else None
        self.problem = problem
        self.fix = fix
        where = f"{self.path}: " if self.path else ""
        # one line whatever the input held (a header cell or YAML key with a line break)
        super().__init__(" ".join(f"{where}{problem}; fix: {fix}".splitlines()))


def error_line(e, prog: str = "qr") -> str:
    """The line a user sees for bad input ``e`` (a :class:`QrInputError`, or its text): the program, then the error."""
    return f"{prog}: error: {e}"


class QrInputWarning(UserWarning):
    """Legal but suspicious input (the message names the fix)."""


def warn(path: str | Path | None, problem: str, fix: str) -> None:
    where = f"{path}: " if path else ""
    warnings.warn(f"{where}{problem}; fix: {fix}", QrInputWarning, stacklevel=2)


@contextlib.contextmanager
def job_log(path: str | Path) -> Iterator[IO[str]]:
    """A workflow job's log: stderr goes to the file; an error that ends the job is written to it and to the
    job's own stderr (Snakemake's output), one line for bad input (exit status 2, as ``qr``), the traceback
    otherwise.  (Redirected by hand, the error came after the file was closed and was lost:
    "lost sys.stderr", nothing in either place.)"""
    own = sys.stderr
    with open(path, "w") as log:
        sys.stderr = log
        try:
            yield log
        except QrInputError as e:
            for out in (log, own):
                print(error_line(e), file=out, flush=True)
            sys.stderr = own
            raise SystemExit(EXIT_BAD_INPUT) from None
        except BaseException:
            traceback.print_exc(file=log)  # the original stderr gets it from Python, after the file is closed
            raise
        finally:
            sys.stderr = own
