"""The link segments' end points of one decision, as the status draws them: a value that compares by value.

:class:`gateway.core.RobotDecision` carries it, so that two decisions still compare with ``==`` (a NamedTuple
holding bare numpy arrays would raise on comparison).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


class LinkEnds:
    """End points of every link segment, world frame, shape (L, 3) each [m]; equal when every coordinate is."""

    __slots__ = ("p_a_world", "p_b_world")

    def __init__(self, p_a_world: FloatArray, p_b_world: FloatArray) -> None:
        self.p_a_world = p_a_world
        self.p_b_world = p_b_world

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LinkEnds):
            return NotImplemented
        return bool(np.array_equal(self.p_a_world, other.p_a_world) and np.array_equal(self.p_b_world, other.p_b_world))

    __hash__ = None  # type: ignore[assignment]  # mutable arrays: not hashable

    def __repr__(self) -> str:
        return f"LinkEnds({len(self.p_a_world)} links)"
