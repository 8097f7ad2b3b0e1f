"""User-facing errors: one line naming the file, the problem and the fix."""

from __future__ import annotations

import warnings
from pathlib import Path

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


class QrInputWarning(UserWarning):
    """Legal but suspicious input (the message names the fix)."""


def warn(path: str | Path | None, problem: str, fix: str) -> None:
    where = f"{path}: " if path else ""
    warnings.warn(f"{where}{problem}; fix: {fix}", QrInputWarning, stacklevel=2)
