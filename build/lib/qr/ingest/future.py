"""Extension points for sources not yet supported: they fail with the way forward."""

from ..errors import QrInputError


def rosbag(path):
    raise QrInputError(path, "ROS bag input is not supported yet",
                       "export the mocap pose and rotor speeds to the canonical CSV "
                       "(docs/spec/flight-log.md), or add qr/ingest/rosbag.py (see qr/ingest/__init__.py)")
