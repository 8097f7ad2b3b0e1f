"""Adapters from raw logs to the canonical flight (``flight-log.md``).

Each adapter is a function ``read(path) -> DataFrame`` (canonical columns, SI,
rotor speeds in the unit the source logs) registered in ``ADAPTERS``; detection
by content is in ``detect_format``.  To add a source (a ROS bag, a public data set), write
``ingest/<name>.py`` with such a ``read`` and register it.  An adapter may set ``attrs["sources"]`` (what it
read) and ``attrs["rotor_input"]`` (``"command"``: normalised motor commands, not rotor speeds).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..errors import QrInputError
from ..flight import validate_flight
from . import cf_usd, csv, future, ulog

ADAPTERS = {
    "csv": csv.read,
    "cf-usd": cf_usd.read,
    "ulog": ulog.read,
    "rosbag": future.rosbag,
}


def detect_format(path: Path) -> str:
    with open(path, "rb") as f:
        head = f.read(16)
    if head[:1] == cf_usd.MAGIC:
        return "cf-usd"
    if head.startswith(b"ULog"):
        return "ulog"
    if head.startswith(b"#ROSBAG") or path.suffix in (".bag", ".mcap", ".db3"):
        return "rosbag"
    return "csv"


def read_log(src: str | Path, vehicle, fmt: str = "auto") -> pd.DataFrame:
    """Read ``src`` in ``fmt`` (or detect it) and validate it against ``vehicle`` (the stage that writes
    it is :mod:`qr.stages.ingest`)."""
    src = Path(src)
    if not src.exists():
        raise QrInputError(src, "log file does not exist", "check the path")
    if src.is_dir():
        raise QrInputError(src, "is a folder, not a log file", "give the log file itself (e.g. FOLDER/log00)")
    if src.stat().st_size == 0:
        raise QrInputError(src, "log file is empty", "point at a complete log (a failed recording is 0 bytes)")
    if fmt == "auto":
        fmt = detect_format(src)
    if fmt not in ADAPTERS:
        raise QrInputError(src, f"unknown format '{fmt}'", f"use one of auto, {', '.join(ADAPTERS)}")
    df = ADAPTERS[fmt](src)
    if df.attrs.get("rotor_input") == "command":
        raise QrInputError(src, f"the log has motor commands ({df.attrs['sources']['rotors']}), not measured "
                                "rotor speeds, and command -> thrust maps (rotor_input: command) are not "
                                "supported yet",
                           "log ESC telemetry (PX4: esc_status, from DShot or UAVCAN ESCs) so the rotor speeds "
                           "are in the log")
    return validate_flight(df, src, vehicle)
