"""Settings of `terra serve`: where it listens, who may ask, and how much one request may carry."""

from __future__ import annotations

from pydantic import Field

from terra.schemas import Section

LOOPBACK = "127.0.0.1"
TOKEN_ENV = "TERRA_SERVE_TOKEN"


class ServeConfig(Section):
    """HTTP service limits. A request over a limit is refused with 413 before any work is done."""

    host: str = Field(
        default=LOOPBACK, description="Address to bind; loopback by default (other machines cannot connect)."
    )
    port: int = Field(default=8765, ge=0, le=65535, description="TCP port.")
    token: str | None = Field(
        default=None, min_length=8, description=f"Bearer token every request must carry (also ${TOKEN_ENV})."
    )
    allow_writes: bool = Field(
        default=False,
        description='Accept requests that change the bundle (POST /find with "save": true); off: read-only.',
    )
    max_body_bytes: int = Field(default=65536, ge=256, description="Largest request body accepted, bytes.")
    max_queries: int = Field(default=32, ge=1, description="Most text queries in one request.")
    max_query_chars: int = Field(default=1000, ge=1, description="Longest text query, characters.")


class LiveConfig(Section):
    """`terra serve --live`: how pushed frames are taken and how often the map is committed."""

    update_every: float = Field(
        default=2.0, gt=0.0, le=3600.0, description="Seconds between snapshots (map and graph committed)."
    )
    update_frames: int | None = Field(
        default=None, ge=1, description="Also commit after this many new fused frames (None: by time only)."
    )
    max_frame_bytes: int = Field(
        default=64 << 20, ge=1024, description="Largest POST /frames body accepted, bytes (more: 413)."
    )
