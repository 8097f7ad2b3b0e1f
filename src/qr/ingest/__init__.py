"""Adapters from raw logs to the canonical flight (``flight-log.md``).

Each adapter is a function ``read(path) -> DataFrame`` (canonical columns, SI,
rotor speeds in the unit the source logs) registered in ``ADAPTERS``; detection
by content is in ``detect_format``.  To add a source (a ROS bag, a public data set), write
``ingest/<name>.py`` with such a ``read`` and register it.  An adapter may set ``attrs["sources"]`` (what it
read) and ``attrs["rotor_input"]`` (``"command"``: u1..u4 are normalised motor commands, not rotor speeds),
or give the commands beside the speeds (``cmd1..cmd4``): the vehicle's ``rotor_input`` chooses.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import QrInputError
from ..flight import ROTORS, to_spec_frames, validate_flight
from ..vehicle import SPEED_IN_RPM
from . import cf_usd, csv, rosbag, ulog

ADAPTERS = {
    "csv": csv.read,
    "parquet": csv.read,  # read by content: CSV or Parquet
    "cf-usd": cf_usd.read,
    "ulog": ulog.read,
    "rosbag": rosbag.read,
}


def detect_format(path: Path) -> str:
    if path.is_dir():
        return "rosbag" if (path / "metadata.yaml").exists() else "folder"
    with open(path, "rb") as f:
        head = f.read(16)
    if head[:1] == cf_usd.MAGIC:
        return "cf-usd"
    if head.startswith(b"ULog"):
        return "ulog"
    if head.startswith(b"#ROSBAG"):
        return "rosbag"
    if head.startswith(b"\x89MCAP") or head.startswith(b"SQLite format 3"):
        return "rosbag-file"
    return "csv"


# formats whose frames the reader knows (and converts itself)
FRAMES_KNOWN = {"ulog": "read from PX4's NED / FRD by the ULog reader", "cf-usd": "the Crazyflie's own ENU / FLU"}
COMMANDS = ["cmd1", "cmd2", "cmd3", "cmd4"]  # an adapter's motor commands beside the rotor speeds, in [0, 1]


def read_log(src: str | Path, vehicle, fmt: str = "auto", topics: dict | None = None,
             frame: str = "enu-flu") -> pd.DataFrame:
    """Read ``src`` in ``fmt`` (or detect it), its frames ``frame`` converted to the spec's
    (:func:`qr.flight.to_spec_frames`), and validate it against ``vehicle`` (the stage that writes it is
    :mod:`qr.stages.ingest`)."""
    src = Path(src)
    if not src.exists():
        raise QrInputError(src, "log file does not exist", "check the path")
    kind = detect_format(src)
    if kind == "folder":
        raise QrInputError(src, "is a folder, not a log file (nor a ROS 2 bag: no metadata.yaml)",
                           "give the log file itself (e.g. FOLDER/log00), or a ROS 2 bag's folder")
    if kind == "rosbag-file":
        raise QrInputError(src, "is one storage file of a ROS 2 bag (.mcap or .db3)",
                           "give the bag's folder, the one holding metadata.yaml")
    if not src.is_dir() and src.stat().st_size == 0:
        raise QrInputError(src, "log file is empty", "point at a complete log (a failed recording is 0 bytes)")
    if fmt == "auto":
        fmt = kind
    if fmt not in ADAPTERS:
        raise QrInputError(src, f"unknown format '{fmt}'", f"use one of auto, {', '.join(ADAPTERS)}")
    if topics and fmt != "rosbag":
        raise QrInputError(src, f"--topic is for ROS bags, and this log is {fmt}", "leave --topic out")
    if frame != "enu-flu" and fmt in FRAMES_KNOWN:
        raise QrInputError(src, f"--frame {frame} is for CSV, Parquet and ROS bag logs, and this log is {fmt}, "
                                f"{FRAMES_KNOWN[fmt]}", "leave --frame out")
    df = ADAPTERS[fmt](src, topics) if fmt == "rosbag" else ADAPTERS[fmt](src)
    df = to_spec_frames(df, frame, src)
    unit = df.attrs.get("rotor_unit")
    if unit and vehicle is not None and unit != vehicle.rotor_speed_unit:  # rotor speeds in the vehicle's unit
        for c in ("u1", "u2", "u3", "u4"):
            df[c] = df[c] * SPEED_IN_RPM[unit] / SPEED_IN_RPM[vehicle.rotor_speed_unit]
    wanted = vehicle.rotor_input if vehicle is not None else "speed"
    if all(c in df for c in COMMANDS):  # a log with both (Crazyflie: rpm and PWM): the vehicle chooses
        if wanted == "command":
            df[ROTORS] = df[COMMANDS].to_numpy()
            df.attrs = {**df.attrs, "rotor_input": "command", "sources": {**df.attrs.get("sources", {}),
                                                                           "rotors": "motor commands"}}
        df = df.drop(columns=COMMANDS)
    logged = df.attrs.get("rotor_input", "speed")
    if logged == "command" and wanted != "command":
        raise QrInputError(src, f"the log has motor commands ({df.attrs['sources']['rotors']}), not measured "
                                "rotor speeds, and the vehicle file has no command -> thrust map",
                           "add rotor_input: command and command_map: {a, b, k} to the vehicle file "
                           "(docs/ingest.md), or log ESC telemetry (PX4: esc_status)")
    if wanted == "command":
        df = commands_to_speeds(df, vehicle, src)
    return validate_flight(df, src, vehicle)


def commands_to_speeds(df: pd.DataFrame, vehicle, src) -> pd.DataFrame:
    """u1..u4 as normalised commands -> the equivalent rotor speeds of the vehicle's command map
    (:class:`qr.rotors.CommandMap`), with ``vbat`` where the map has a reference voltage."""
    c = df[ROTORS].to_numpy(dtype=float)
    seen = c[np.isfinite(c)]
    if seen.size and (seen.min() < -0.01 or seen.max() > 1.01):
        raise QrInputError(src, f"the vehicle reads u1..u4 as commands in [0, 1] (rotor_input: command), and "
                                f"they span {seen.min():.4g} to {seen.max():.4g}",
                           "normalise the commands to [0, 1] (PWM: (pwm - min) / (max - min)), or set "
                           "rotor_input: speed if these are rotor speeds")
    m = vehicle.command_map
    vbat = df["vbat"].to_numpy(dtype=float) if m.v_ref is not None and "vbat" in df else None
    out = df.copy()
    out[ROTORS] = m.equivalent_speeds(np.clip(c, 0.0, 1.0), vehicle.thrust_coeff, vbat)
    out.attrs = {**df.attrs, "rotor_input": "command"}
    return out
