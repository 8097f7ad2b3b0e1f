"""The canonical flight log (``docs/spec/flight-log.md``): read, validate, write.

A flight is a ``pandas.DataFrame`` with the spec's columns in SI units (rotor
speeds in the vehicle's ``rotor_speed_unit``); ``NaN`` marks a dropout.  CSV is
the exchange format; Parquet is the fast format between workflow stages.
"""

from __future__ import annotations

import csv
import difflib
import gzip
import io
import zlib
from pathlib import Path

import numpy as np
import pandas as pd

from .atomic import atomic_path
from .errors import QrInputError, warn
from .frames import make_continuous
from .rotors import HOVER_RATIO_LIMITS
from .vehicle import SPEED_IN_RPM

POSITION = ["px", "py", "pz"]
QUATERNION = ["qw", "qx", "qy", "qz"]
ROTORS = ["u1", "u2", "u3", "u4"]
REQUIRED = ["t", *POSITION, *QUATERNION, *ROTORS]
ACCEL = ["ax", "ay", "az"]  # accelerometer: specific force, body frame, m/s²
GYRO = ["gx", "gy", "gz"]  # gyro: body rate, rad/s
OPTIONAL = [*ACCEL, *GYRO, "vbat"]
VELOCITY = ["vx", "vy", "vz"]  # a world-frame velocity some exports carry (not a spec column: carried along)
# the frames a CSV may be written in (qr ingest --frame): world / body
FRAMES = {"enu-flu": "ENU world, FLU body (docs/spec/flight-log.md)", "ned-frd": "NED world, FRD body (PX4's)"}
QUAT_NORM_TOL = 0.05  # |‖q‖ - 1| above this is not a rounding error


def _error(path, problem, fix):
    return QrInputError(path, problem, fix)


def read_flight(path: str | Path, vehicle=None) -> pd.DataFrame:
    """Read a canonical CSV or Parquet flight, validated and normalised.

    The format is told by the content, not the name (a Parquet file named ``.csv`` reads as
    Parquet; gzip-compressed CSV is decompressed).  ``df.attrs['source']`` names the file.
    """
    path = Path(path)
    if not path.exists():
        raise _error(path, "flight file does not exist", "check the path")
    if path.is_dir():
        inside = sorted(p.name for p in path.iterdir() if p.suffix in (".csv", ".parquet"))[:3]
        raise _error(path, "is a folder, not a flight file",
                     "give the flight's CSV or Parquet file" + (f" (it holds {', '.join(inside)})" if inside else ""))
    try:
        data = path.read_bytes()
    except OSError as e:
        raise _error(path, f"flight file cannot be read ({e.strerror})", "check its permissions") from None
    if not data:
        raise _error(path, "flight file is empty", "give a CSV with a header row and one row per sample")
    if data[:2] == GZIP_MAGIC:
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error):
            raise _error(path, "gzip-compressed file is truncated or damaged", "copy or compress it again") from None
    if data[:4] == PARQUET_MAGIC:
        df = _read_parquet(path, data)
    else:
        df = _read_csv(path, _text(path, data))
    df = validate_flight(df, path, vehicle)
    df.attrs["source"] = str(path)
    return df


GZIP_MAGIC, PARQUET_MAGIC = b"\x1f\x8b", b"PAR1"
OTHER_FORMATS = {b"PK\x03\x04": "a zip archive", b"BZh": "bzip2-compressed", b"\xfd7zXZ": "xz-compressed",
                 b"\x28\xb5\x2f\xfd": "zstd-compressed", b"\x89HDF": "an HDF5 file", b"ULog": "a PX4 ULog",
                 b"#ROSBAG": "a ROS bag"}
DELIMITERS = {";": "semicolons", "\t": "tabs", "|": "vertical bars", " ": "spaces"}


def _read_parquet(path: Path, data: bytes) -> pd.DataFrame:
    try:
        return pd.read_parquet(io.BytesIO(data))
    except Exception as e:  # pyarrow raises several types for a damaged file
        raise _error(path, f"Parquet file cannot be read ({str(e).splitlines()[0][:120]})",
                     "write it again (a partial or damaged file cannot be trusted), or give the CSV") from None


def _text(path: Path, data: bytes) -> str:
    for magic, what in OTHER_FORMATS.items():
        if data.startswith(magic):
            raise _error(path, f"is {what}, not a CSV or Parquet flight",
                         "extract or convert it to the canonical CSV (qr ingest reads the Crazyflie uSD logs)")
    if b"\x00" in data[:65536]:
        raise _error(path, "is a binary file, not a CSV or Parquet flight",
                     "give the canonical CSV of docs/spec/flight-log.md (or a Parquet file)")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = data[:e.start].count(b"\n") + 1
        raise _error(path, f"is not UTF-8 text (byte 0x{data[e.start]:02x} at line {line})",
                     "save the CSV as UTF-8 (the flight columns are plain ASCII)") from None


def _header(path: Path, text: str) -> list[str]:
    try:
        first = next(csv.reader(io.StringIO(text, newline=""), skipinitialspace=True), [])
    except csv.Error as e:
        raise _error(path, f"malformed CSV header ({e})", "write one header row of comma-separated names") from None
    # an empty name (a trailing comma) gets one, so that two of them are not "the same column"
    return [c.strip() or f"unnamed_{i + 1}" for i, c in enumerate(first)]


def _check_delimiter(path: Path, header: list[str], text: str):
    """A header that only splits into the spec's names on another character: say which."""
    if all(c in header for c in REQUIRED):
        return
    line = text.splitlines()[0] if text else ""
    for d, name in DELIMITERS.items():
        cells = [c.strip() for c in (line.split() if d == " " else line.split(d))]
        if sum(c in REQUIRED for c in cells) > len(REQUIRED) // 2:
            raise _error(path, f"the cells are separated by {name}, not commas",
                         "write a comma-separated file (docs/spec/flight-log.md), "
                         "e.g. pandas df.to_csv(path, index=False)")


def _check_row_lengths(path: Path, text: str, n: int):
    """Every row has the header's number of cells (pandas would shift or cut a longer row, pad a shorter one)."""
    if '"' not in text:  # no quoting: a row's cells are its commas plus one (the csv module is 10x slower)
        for line, row in enumerate(text.splitlines(), 1):
            if row and row.count(",") + 1 != n:
                break
        else:
            return
    try:
        for line, row in enumerate(csv.reader(io.StringIO(text, newline=""), skipinitialspace=True), 1):
            if row and len(row) != n:
                raise _error(path, f"line {line} has {len(row)} cells, the header {n}"
                                   + (" (a truncated line?)" if len(row) < n else ""),
                             "every row needs one comma-separated cell per header column (empty for a dropout)")
    except csv.Error as e:
        raise _error(path, f"malformed CSV ({e})", "write plain comma-separated numbers") from None


def _read_csv(path: Path, text: str) -> pd.DataFrame:
    if not text.strip():
        raise _error(path, "flight file is empty", "give a CSV with a header row and one row per sample")
    cols = _header(path, text)
    _check_delimiter(path, cols, text)
    _check_columns(path, cols)  # on the header itself: pandas renames a repeated name (px, px.1)
    _check_row_lengths(path, text, len(cols))
    numeric = [c for c in cols if c in REQUIRED or c in OPTIONAL]
    opts = dict(header=0, names=cols, skipinitialspace=True, index_col=False)
    try:
        df = pd.read_csv(io.StringIO(text), dtype={c: "float64" for c in numeric}, **opts)
    except (ValueError, TypeError, OverflowError) as e:
        if isinstance(e, pd.errors.ParserError):
            raise _error(path, f"malformed CSV ({str(e).splitlines()[0]})",
                         "every row needs as many comma-separated cells as the header") from None
        try:
            df = pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False, **opts)
        except (ValueError, TypeError) as e2:
            raise _error(path, f"malformed CSV ({str(e2).splitlines()[0]})",
                         "every row needs as many comma-separated cells as the header") from None
        _raise_first_non_numeric(path, df, numeric)
        raise _error(path, "the CSV cannot be parsed as numbers",
                     "write one number per cell, comma separated") from None
    if len(df) == 0:
        raise _error(path, "flight file has a header but no samples", "export the flight's rows too")
    return df


def _raise_first_non_numeric(path, df, numeric):
    for c in numeric:
        s = df[c].astype(str).str.strip()
        vals = pd.to_numeric(s.where(s != "", None), errors="coerce")
        bad = vals.isna() & (s != "") & ~s.str.lower().isin(["nan"])
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise _error(path, f"non-numeric value {s.iloc[i]!r} in column '{c}' at line {i + 2}",
                         "write numbers only (leave the cell empty for a dropout)")


def _check_columns(path, cols):
    dup = sorted({c for c in cols if cols.count(c) > 1})
    if dup:
        raise _error(path, f"column(s) {dup} appear more than once", "keep one column of each name")
    missing = [c for c in REQUIRED if c not in cols]
    if missing:
        hints = []
        for m in missing:
            close = difflib.get_close_matches(m, [c for c in cols if c not in REQUIRED], n=1, cutoff=0.5)
            hints.append(f"'{m}'" + (f" (found {close[0]!r}: misspelled?)" if close else ""))
        raise _error(path, f"missing column(s) {', '.join(hints)}",
                     f"the header must contain {', '.join(REQUIRED)} (docs/spec/flight-log.md)")


def validate_flight(df: pd.DataFrame, path=None, vehicle=None) -> pd.DataFrame:
    """Check a flight against the spec and return it normalised.

    Errors are raised for unusable input; legal but messy input is repaired:
    quaternion sign flips are made continuous, quaternions renormalised, blank
    cells kept as NaN (dropouts), unknown columns carried along at the end.
    """
    cols = [str(c) for c in df.columns]
    _check_columns(path, cols)
    if len(df) == 0:
        raise _error(path, "flight has no samples", "export the flight's rows too")
    df = df.copy()
    for c in [c for c in cols if c in REQUIRED or c in OPTIONAL]:
        if not pd.api.types.is_numeric_dtype(df[c]):
            _raise_first_non_numeric(path, df.astype({c: str}), [c])
            df[c] = pd.to_numeric(df[c])
        df[c] = df[c].astype("float64")

    t = df["t"].to_numpy()
    if not np.isfinite(t).all():
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        what = "missing" if np.isnan(t[i]) else f"{t[i]} (not a number of seconds)"
        raise _error(path, f"time stamp {what} at data row {i + 1}", "every row needs a finite time stamp t (s)")
    dt = np.diff(t)
    if (dt == 0).any():
        i = int(np.flatnonzero(dt == 0)[0])
        raise _error(path, f"duplicated time stamp t={t[i]:.6f} at data rows {i + 1} and {i + 2}",
                     "drop the repeated row (or fix the clock) so t is strictly increasing")
    if (dt < 0).any():
        i = int(np.flatnonzero(dt < 0)[0])
        raise _error(path, f"time stamps not strictly increasing (t={t[i]:.6f} then {t[i + 1]:.6f} "
                           f"at data rows {i + 1}-{i + 2})", "sort the rows by t, or fix the clock")
    _check_time_unit(path, t)
    _infinite_to_dropouts(path, df, [c for c in cols if c in REQUIRED[1:] or c in OPTIONAL])

    q = df[QUATERNION].to_numpy()
    with np.errstate(over="ignore"):  # absurd values overflow to inf, refused below
        n = np.linalg.norm(q, axis=1)
    far = np.isfinite(n) & (np.abs(n - 1.0) > QUAT_NORM_TOL)
    if far.any():
        i = int(np.flatnonzero(far)[0])
        raise _error(path, f"quaternion norm {n[i]:.3f} at data row {i + 1} (t={t[i]:.3f}) is far from 1",
                     "give unit quaternions [qw, qx, qy, qz] (scalar first), not Euler angles or a scaled q")
    q_part = np.isfinite(q).any(axis=1) & ~np.isfinite(q).all(axis=1)
    q[q_part] = np.nan
    q = make_continuous(q / n[:, None])
    df[QUATERNION] = q

    u = df[ROTORS].to_numpy()
    if (u < 0).any():
        r, c = np.argwhere(u < 0)[0]
        raise _error(path, f"negative rotor speed {u[r, c]:g} in '{ROTORS[c]}' at data row {r + 1}",
                     "give rotor speed magnitudes (the layout's yaw_sign carries the direction)")
    check_not_frozen(df, path)
    if vehicle is not None:
        check_hover_ratio(df, vehicle, path)

    extra = [c for c in cols if c not in REQUIRED and c not in OPTIONAL]
    opt = [c for c in OPTIONAL if c in cols]
    return df[REQUIRED + opt + extra].reset_index(drop=True)


# a quadrotor log's sample period lies between ~0.1 ms and 1 s, and a flight lasts less than a day
PLAUSIBLE_STEP_S = (1e-4, 1.0)
# the bounds hold to 1 %: a 10 kHz log stamped in epoch seconds steps by 1e-4 s ± 2.4e-7 s (float64's resolution
# at 1.7e9 s), and a log in milliseconds or microseconds lies orders of magnitude away
STEP_TOLERANCE = 0.01
PLAUSIBLE_SPAN_S = 86400.0
TIME_UNITS = {1e3: ("milliseconds", "1000"), 1e6: ("microseconds", "1e6"), 1e9: ("nanoseconds", "1e9")}


def _check_time_unit(path, t: np.ndarray) -> None:
    """Refuse time stamps that cannot be seconds (a log in ms or µs), naming the likely unit."""
    if len(t) < 2:
        return
    step, span = float(np.median(np.diff(t))), float(t[-1] - t[0])
    lo, hi = PLAUSIBLE_STEP_S[0] * (1 - STEP_TOLERANCE), PLAUSIBLE_STEP_S[1] * (1 + STEP_TOLERANCE)
    if lo <= step <= hi and span <= PLAUSIBLE_SPAN_S:
        return
    seen = f"median step {step:.4g}, span {span:.4g} over {len(t)} rows"
    fits = [f for f in TIME_UNITS if lo <= step / f <= hi and span / f <= PLAUSIBLE_SPAN_S]
    if fits:  # the unit whose rate is closest to a typical 100 Hz
        f = min(fits, key=lambda f: abs(np.log10(step / f / 0.01)))
        unit, div = TIME_UNITS[f]
        raise _error(path, f"time stamps look like {unit}, not seconds ({seen}: {step / f:.4g} s per sample "
                           f"in seconds)", f"divide t by {div} so it is in seconds")
    raise _error(path, f"time stamps cannot be seconds ({seen}; a sample period lies between "
                       f"{PLAUSIBLE_STEP_S[0]:g} and {PLAUSIBLE_STEP_S[1]:g} s and a flight lasts less than a day)", "give t in seconds")


def _infinite_to_dropouts(path, df: pd.DataFrame, cols: list[str]) -> None:
    """An infinite sensor value is a sensor fault: a dropout of that sensor (NaN), with one warning."""
    vals = df[cols].to_numpy()
    bad = np.isinf(vals)
    if not bad.any():
        return
    r, c = np.argwhere(bad)[0]
    where = ", ".join(f"{cols[k]} ({int(n)})" for k, n in enumerate(bad.sum(axis=0)) if n)
    df[cols] = np.where(bad, np.nan, vals)
    warn(path, f"{int(bad.sum())} infinite value(s) in {where}, first at data row {r + 1} "
               f"(t={df['t'].iloc[r]:.3f}): read as dropouts of that sensor",
         "check the logger; blank cells mark dropouts")


def check_not_frozen(df: pd.DataFrame, path=None, rotors: bool = False) -> None:
    """Refuse a measured signal that never changes: a frozen stream, not a measurement.

    Motion capture always carries noise, so an attitude (or position) identical in every
    sample is a stuck stream; the filters cannot estimate noise or rates from it.  ``rotors``:
    also refuse four rotor speeds that never change (``filter=auto`` needs their noise too).
    """
    groups = [("position", POSITION), ("attitude", QUATERNION)] + ([("rotor speeds", ROTORS)] if rotors else [])
    for name, cols in groups:
        a = df[cols].to_numpy(dtype=float)
        ok = np.isfinite(a).all(axis=1)
        if ok.sum() > 1 and np.all(a[ok] == a[ok][0]):
            raise _error(path, f"every sample has the same {name} ({', '.join(cols)}): it never changes, "
                               "as from a frozen stream",
                         "check the recording: a real measurement always varies, at least by the sensor noise")


def hover_ratio(df: pd.DataFrame, vehicle) -> float:
    """Median rotor-map thrust over m g while the rotors work: near 1 for a flight with consistent units.

    Rows with the motors off or idling (below a quarter of the log's high thrust, its 99th
    percentile) do not count: a log may spend most of its time on the ground.
    """
    u = df[ROTORS].to_numpy()
    ok = np.isfinite(u).all(axis=1)
    if not ok.any():
        return float("nan")
    with np.errstate(over="ignore", invalid="ignore"):  # absurd speeds give inf: a ratio out of range
        T, _ = vehicle.rotors.thrust_torque(u[ok])
    if not np.isfinite(T).all():
        return float("inf")
    high = np.percentile(T, 99)
    if high <= 0:
        return float("nan")  # the rotors never turn: no unit to check
    return float(np.median(T[T >= 0.25 * high]) / (vehicle.mass * 9.81))


def check_hover_ratio(df, vehicle, path=None):
    ratio = hover_ratio(df, vehicle)
    lo, hi = HOVER_RATIO_LIMITS
    if not np.isnan(ratio) and not lo <= ratio <= hi:
        unit = vehicle.rotor_speed_unit
        other = "rad_s" if unit == "rpm" else "rpm"
        if vehicle.rotor_input == "command" and np.nanmax(np.abs(df[ROTORS].to_numpy(dtype=float))) <= 1.01:
            raise _error(path, "u1..u4 look like motor commands, not rotor speeds",
                         "convert them first: qr ingest FLIGHT --vehicle V.yaml --out flight.csv (the vehicle's "
                         "command_map gives the equivalent rotor speeds)")
        # speeds logged in the other unit: rescaling them to the declared unit rescales T by this
        factor = (SPEED_IN_RPM[other] / SPEED_IN_RPM[unit]) ** 2
        problem = (f"rotor speeds give a median thrust of {ratio:.3g} x m g (plausible: {lo:.2f}-{hi:.0f}); a unit "
                   "or coefficient error")
        if lo <= ratio * factor <= hi:
            raise _error(path, problem, other_speed_unit_fix(vehicle))
        raise _error(path, problem, f"check rotor_speed_unit ({unit}) and thrust_coeff in the vehicle file, "
                                    f"and that u1..u4 are rotor speeds")


def other_speed_unit_fix(vehicle) -> str:
    """The whole fix for rotor speeds logged in the other unit than the vehicle file's: convert the log, or
    switch the file's unit *and* its coefficients (C_T and C_Q are per unit², so they scale by the square)."""
    unit = vehicle.rotor_speed_unit
    other = "rad_s" if unit == "rpm" else "rpm"
    k = SPEED_IN_RPM[other] / SPEED_IN_RPM[unit]  # one `other` in `unit`s
    per = "60/2π" if other == "rad_s" else "2π/60"
    return (f"the speeds look like {other}, not {unit}: either multiply u1..u4 by {per} = {k:.6g} "
            f"(to {unit}), or set rotor_speed_unit: {other} in the vehicle file together with "
            f"thrust_coeff: {vehicle.thrust_coeff * k**2:.6g} and torque_coeff: {vehicle.torque_coeff * k**2:.6g} "
            f"(C_T and C_Q are per unit², so both x ({per})² = {k**2:.6g}: now {vehicle.thrust_coeff:.6g} and "
            f"{vehicle.torque_coeff:.6g})")


def write_flight(df: pd.DataFrame, path: str | Path) -> None:
    """Write CSV (``.csv``) or Parquet (``.parquet``) atomically, every value read back to the bit: the CSV
    holds each float's shortest round-trip decimal (an epoch stamp, ~1.7e9 s, keeps its microseconds)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if path.suffix == ".parquet":
            df.to_parquet(tmp, index=False)
        else:
            df.to_csv(tmp, index=False, float_format=None)


def to_spec_frames(df: pd.DataFrame, frame: str, path=None) -> pd.DataFrame:
    """A flight written in ``frame`` (:data:`FRAMES`) in the spec's ENU world / FLU body: positions,
    velocity (``vx, vy, vz``, where all three are there), attitude (:func:`qr.frames.from_ned_frd`), gyro and
    accelerometer (their y and z negated, each column that is there); every other column as it was."""
    if frame not in FRAMES:
        raise _error(path, f"unknown frame '{frame}'", f"use one of {', '.join(FRAMES)}")
    if frame == "enu-flu":
        return df
    from .frames import NED_TO_ENU, from_ned_frd

    out = df.copy()
    out[POSITION], out[QUATERNION] = from_ned_frd(df[POSITION].to_numpy(float), df[QUATERNION].to_numpy(float))
    given = [c for c in VELOCITY if c in df]
    if given and len(given) < 3:
        raise _error(path, f"the velocity has {', '.join(given)} but not {', '.join(sorted(set(VELOCITY) - set(given)))}",
                     "give vx, vy, vz together (a NED velocity is converted as a whole), or none")
    if given:
        out[VELOCITY] = df[VELOCITY].to_numpy(float) @ NED_TO_ENU.T
    for c in ("ay", "az", "gy", "gz"):  # FRD -> FLU body: y and z turn over, x stays
        if c in df:
            out[c] = -df[c].to_numpy(float)
    return out


def dropouts(df: pd.DataFrame) -> dict:
    """Counts of missing samples: blank cells per sensor, and stamps gaps above 1.5x the median step."""
    t = df["t"].to_numpy()
    dt = np.diff(t)
    med = float(np.median(dt)) if len(dt) else float("nan")
    gaps = int(np.sum(np.round(dt[dt > 1.5 * med] / med) - 1)) if len(dt) else 0
    return {
        "mocap_blank": int(df[POSITION + QUATERNION].isna().any(axis=1).sum()),
        "rotor_blank": int(df[ROTORS].isna().any(axis=1).sum()),
        "missed_frames": gaps,
        "median_dt": med,
    }


def on_stamps(rows: pd.DataFrame, t) -> pd.DataFrame:
    """A flight's rows at a state table's stamps (the same samples, matched within 1 µs; others blank)."""
    return rows.set_index("t").reindex(np.asarray(t, float), method="nearest", tolerance=1e-6).reset_index()
