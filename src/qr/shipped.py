"""What ships inside the package: the Hydra config tree and the vehicles found there by name.

``src/qr/conf`` is a link to the checkout's ``conf/``, so an installed qr (``pip install .``: the link's
files are package data) finds the same tree from any folder; ``QR_CONF`` points elsewhere.  A leaf
module: the vehicle loader and the Hydra set-up both read it, neither through the other.
"""

from __future__ import annotations

import os
from pathlib import Path

CONF_DIR = str(Path(os.environ.get("QR_CONF", Path(__file__).parent / "conf")).resolve())


def vehicle_file(name_or_path, conf: str | Path | None = None) -> Path:
    """The file of a vehicle given by path, or by the bare name of a shipped one
    (``asctec_hummingbird``: ``<conf>/vehicle/asctec_hummingbird.yaml``; ``conf``: the config tree,
    default :data:`CONF_DIR`).  A name that ships nothing is returned as given (its loader says so)."""
    path = Path(name_or_path)
    if path.is_file() or path.suffix in (".yaml", ".yml") or str(path) != path.name:
        return path
    shipped = Path(CONF_DIR if conf is None else conf) / "vehicle" / f"{path.name}.yaml"
    return shipped if shipped.is_file() else path


def shipped_vehicles() -> list[str]:
    """The names of the shipped vehicles (``conf/vehicle/*.yaml``)."""
    return sorted(p.stem for p in (Path(CONF_DIR) / "vehicle").glob("*.yaml"))
