"""Feeds a TrackSet tracker frames as the core does (tests of gateway/tracks.py: tracks and persons)."""

from __future__ import annotations

from gateway.tracks import TrackSet, TrackState
from hrc_contract.config import CellConfig
from hrc_contract.humans import HumanCapsules, merge_humans


class Feed:
    """Each frame a new object, captured at ``t_ns`` (``stamp_late_ns`` earlier for a tracker that stamps late).

    Args:
        by_id: TEST ONLY: the release rule persons replaced (``TrackSet(release_by_id_unsafe=True)``), for the teeth.
    """

    def __init__(self, config: CellConfig, *, by_id: bool = False) -> None:
        self.tracks = TrackSet(config, release_by_id_unsafe=by_id)
        self.frames: dict[str, tuple[object, HumanCapsules, int, None] | None] = dict.fromkeys(config.trackers)

    def see(self, t_ns: int, tracker: str, *people: HumanCapsules, stamp_late_ns: int = 0) -> list[str]:
        """The tracker's frame with these people (none: it sees nobody); the changes as ``kind:track:cause``."""
        self.frames[tracker] = (object(), merge_humans(list(people)), t_ns - stamp_late_ns, None)
        return [f"{e.kind}:{e.track}:{e.cause}" for e in self.tracks.update(self.frames, t_ns)]

    def state(self, label: str) -> TrackState | None:
        for t in (*self.tracks.live, *self.tracks.released):
            if t.label == label:
                return t.state
        return None
