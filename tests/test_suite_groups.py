"""The suite's split over two pytest-xdist workers (run-tests.sh, tests/conftest.py): tests that judge real time run
on the end-to-end tests' worker, and the groups reach the scheduler."""

from __future__ import annotations

import os
import re

import pytest
from conftest import CELLS_MARKERS, xdist_group
from support.paths import REPO_ROOT

REAL_TIME = re.compile(r"zenoh\.open\(|start_program\(|subprocess\.Popen\(")
"""What a module does when it starts a program or opens a Zenoh session: timing it judges depends on the machine."""

NOT_REAL_TIME = {
    "tests/hrc_tools/sim/test_sweep.py": "the sweep command stopped by SIGTERM: judged by its exit and table, not time",
    "tests/gateway/http/test_operator.py": "its program (the HTTP server) is started by its e2e tests only",
}


def test_every_module_that_starts_programs_or_sessions_runs_beside_no_cell() -> None:
    """A module that starts a program or opens a Zenoh session is marked ``e2e`` or ``serial`` as a whole: on a loaded
    2-core machine, beside a cell as well, its timing fails (the fault relay's p95 delay 116 ms for ≤ 115 ms, a
    partition that had passed before the test sent; run 17 in docs/benchmarks.md)."""
    marked = re.compile(rf"^pytestmark = \[?[^\]=]*pytest\.mark\.({'|'.join(CELLS_MARKERS)})\b", re.MULTILINE)
    unmarked = []
    for path in sorted((REPO_ROOT / "tests").rglob("test_*.py")):
        name = path.relative_to(REPO_ROOT).as_posix()
        source = path.read_text()
        if REAL_TIME.search(source) and name not in NOT_REAL_TIME and not marked.search(source):
            unmarked.append(name)
    assert not unmarked, f"mark these modules serial (pytestmark = pytest.mark.serial): {unmarked}"


def test_every_test_is_scheduled_with_its_group(request: pytest.FixtureRequest) -> None:
    """Under ``--dist loadgroup`` xdist appends a test's group to its id and schedules by that suffix. Without it every
    test is a unit of its own, and the two workers start two cells at once (what pytest 9.2 with xdist 3.8 did)."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        pytest.skip("not on an xdist worker (run-tests.sh runs the suite with -n 2 --dist loadgroup)")
    if not request.config.getvalue("loadgroup"):
        pytest.skip("on an xdist worker without --dist loadgroup")
    wrong = []
    for item in request.session.items:
        group = xdist_group(item)  # the module's path is read before the suffix
        if not item.nodeid.endswith(f"@{group}"):
            wrong.append(f"{item.nodeid} (expected its group {group!r})")
    assert not wrong, "\n".join(wrong[:10])
    assert request.node.nodeid.endswith("@tests/test_suite_groups.py")
