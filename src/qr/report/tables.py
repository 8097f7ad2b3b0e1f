"""Tables: CSV for machines plus a Markdown twin for people, both written atomically.

The CSV holds every float's shortest round-trip decimal (read back equal to the bit); the Markdown twin
rounds for reading (``floatfmt``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..atomic import atomic_path, write_text


def write_table(df: pd.DataFrame, csv_path: str | Path, floatfmt: str = ".4g", title: str | None = None) -> None:
    csv_path = Path(csv_path)
    with atomic_path(csv_path) as tmp:
        df.to_csv(tmp, index=False)
    md = (f"### {title}\n\n" if title else "") + df.to_markdown(index=False, floatfmt=floatfmt) + "\n"
    write_text(csv_path.with_suffix(".md"), md)
