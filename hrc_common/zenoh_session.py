"""Zenoh session configuration shared by the three programs.

With no endpoint given, the gateway listens on :data:`DEFAULT_ENDPOINT` and the emulators connect to
it, so that one cell finds itself on one machine over loopback only. Multicast scouting and gossip are
off: peers meet only where they are told to.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import zenoh

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


def session_config(listen: Sequence[str] = (), connect: Sequence[str] = ()) -> zenoh.Config:
    """A peer-mode Zenoh configuration with explicit endpoints and no scouting."""
    conf: dict[str, object] = {
        "mode": "peer",
        "listen": {"endpoints": list(listen)},
        "connect": {"endpoints": list(connect)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        # A frozen peer is seen gone after about a second instead of ten (field notes).
        "transport": {"link": {"tx": {"lease": 1000}}},
    }
    return zenoh.Config.from_json5(json.dumps(conf))
