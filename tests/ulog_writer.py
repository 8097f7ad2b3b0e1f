"""A minimal PX4 ULog writer for the tests: a canonical flight as a PX4 would log it.

Written from the ULog file-format specification (docs.px4.io, "ULog File Format"): the 16-byte header,
the flag-bits message, one format ('F') and one subscription ('A') message per topic, parameters ('P')
and data ('D') messages in time order. Topics: ``vehicle_local_position`` (NED position),
``vehicle_attitude`` (FRD -> NED quaternion), ``actuator_motors`` (normalised motor commands) and,
where given, ``esc_status`` (ESC telemetry rpm). The frame conversion is the inverse of
``qr.frames.from_ned_frd``, written out here from its matrices.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

MAGIC = b"ULog\x01\x12\x35"
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(path: Path, t: np.ndarray, p_enu: np.ndarray, q_enu_flu: np.ndarray, commands: np.ndarray,
               params: dict | None = None, rpm: np.ndarray | None = None) -> Path:
    """``t`` (s), positions (N, 3), attitudes (N, 4, scalar first), motor commands (N, 4) in [0, 1]; with
    ``rpm`` (N, 4) also ESC telemetry (``esc_status``, a nested ``esc_report[4]``, integer rpm as PX4 logs)."""
    us = np.round(np.asarray(t) * 1e6).astype(np.int64) + 1_000_000
    seen = np.all(np.isfinite(p_enu), axis=1) & np.all(np.isfinite(q_enu_flu), axis=1)  # a dropout: no message
    p_ned = np.asarray(p_enu, float) @ ENU_TO_NED.T
    q_ned = np.full((len(us), 4), np.nan)
    R = Rotation.from_quat(np.asarray(q_enu_flu, float)[seen], scalar_first=True).as_matrix()
    q_ned[seen] = Rotation.from_matrix(ENU_TO_NED @ R @ FLU_TO_FRD).as_quat(scalar_first=True)
    topics = [("vehicle_local_position", "uint64_t timestamp;float x;float y;float z;"),
              ("vehicle_attitude", "uint64_t timestamp;float[4] q;"),
              ("actuator_motors", "uint64_t timestamp;float[4] control;")]
    if rpm is not None:
        topics.append(("esc_status", "uint64_t timestamp;esc_report[4] esc;"))
    out = bytearray(MAGIC + bytes([1]) + struct.pack("<Q", int(us[0])))
    out += _msg(b"B", bytes(8) + bytes(8) + struct.pack("<3Q", 0, 0, 0))
    if rpm is not None:
        out += _msg(b"F", b"esc_report:int32_t esc_rpm;")
    for name, fields in topics:
        out += _msg(b"F", f"{name}:{fields}".encode())
    for key, value in (params or {}).items():
        kind = "float" if isinstance(value, float) else "int32_t"
        out += _msg(b"P", bytes([len(f"{kind} {key}")]) + f"{kind} {key}".encode()
                    + struct.pack("<f" if kind == "float" else "<i", value))
    for msg_id, (name, _) in enumerate(topics):
        out += _msg(b"A", struct.pack("<BH", 0, msg_id) + name.encode())
    for k in range(len(us)):
        if seen[k]:
            out += _msg(b"D", struct.pack("<HQ3f", 0, int(us[k]), *p_ned[k]))
            out += _msg(b"D", struct.pack("<HQ4f", 1, int(us[k]), *q_ned[k]))
        out += _msg(b"D", struct.pack("<HQ4f", 2, int(us[k]), *commands[k]))
        if rpm is not None:
            out += _msg(b"D", struct.pack("<HQ4i", 3, int(us[k]), *np.round(rpm[k]).astype(int)))
    Path(path).write_bytes(bytes(out))
    return Path(path)
