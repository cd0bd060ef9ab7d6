"""Live Terra: the map and the scene graph grow while the robot drives (terra.live.Session)."""

from terra.live.frames import LiveFrameError
from terra.live.session import Session, Snapshot

__all__ = ["LiveFrameError", "Session", "Snapshot"]
