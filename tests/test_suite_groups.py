"""The suite's split over two pytest-xdist workers (run-tests.sh, tests/conftest.py) reaches the scheduler."""

from __future__ import annotations

import os

import pytest
from conftest import CELLS_GROUP


def test_every_test_is_scheduled_with_its_group(request: pytest.FixtureRequest) -> None:
    """Under ``--dist loadgroup`` xdist appends a test's group to its id and schedules by that suffix. Without it every
    test is a unit of its own, and the two workers start two cells at once (what pytest 9.2 with xdist 3.8 did)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        pytest.skip("not on an xdist worker (run-tests.sh runs the suite with -n 2 --dist loadgroup)")
    if not request.config.getvalue("loadgroup"):
        pytest.skip("on an xdist worker without --dist loadgroup")
    wrong = []
    for item in request.session.items:
        module = item.nodeid.split("::", 1)[0]
        group = CELLS_GROUP if item.get_closest_marker("e2e") else module
        if not item.nodeid.endswith(f"@{group}"):
            wrong.append(f"{item.nodeid} (expected its group {group!r})")
    assert not wrong, "\n".join(wrong[:10])
    assert request.node.nodeid.endswith("@tests/test_suite_groups.py")
