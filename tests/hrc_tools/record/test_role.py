"""The ``recorder`` role (``hrc-record``): a member of the cell that reads every topic and may put on none.

The table part is pure; the session part runs real Zenoh sessions over mutual TLS with the cell's access
control: a controller's session (listening, enforcing the policy) hears the gateway's overrides, never the
recorder's, while the recorder reads the controller's joint states.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import Override, to_payload
from hrc_runtime.access_control import RECORDER, CellPolicy, may_put
from hrc_runtime.pki import ROLES, CellPki, common_name
from hrc_runtime.zenoh_session import SessionOptions, mutual_tls, session_config
from hrc_tools.cell.procs import free_port, wait_for
from hrc_tools.cert.main import provision_cell

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

FORGED_SEQ = 10**9


def test_recorder_is_a_role_whose_certificate_may_put_nothing(cell_config: CellConfig) -> None:
    policy = CellPolicy.from_config(cell_config)
    assert "recorder" in ROLES
    assert common_name("recorder") == RECORDER == "recorder"
    cell = cell_config.cell
    every_key = [
        *(keys.robot_override(cell, r) for r in cell_config.robots),
        *(keys.robot_state(cell, r) for r in cell_config.robots),
        *(keys.tracker_humans(cell, t) for t in cell_config.trackers),
        keys.gateway_status(cell),
        keys.truth_humans(cell),
    ]
    assert not [k for k in every_key if may_put(policy, RECORDER, k)]
    assert may_put(policy, "gateway", keys.robot_override(cell, "ur5"))  # the table has teeth


@dataclass
class _Heard:
    lock: threading.Lock
    payloads: list[bytes]

    def on_sample(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.payloads.append(sample.payload.to_bytes())

    def overrides(self) -> list[Override]:
        with self.lock:
            return [Override.model_validate_json(p) for p in self.payloads]


@pytest.fixture
def controller(cell_config: CellConfig, tmp_path: Path) -> Iterator[tuple[str, CellPki, zenoh.Session]]:
    """A controller's session listening on TLS with the cell's access control, as the emulator runs it."""
    policy = CellPolicy.from_config(cell_config)
    pki = CellPki(tmp_path / "pki")
    provision_cell(pki, policy)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    options = SessionOptions("peer", mutual_tls(pki.root, "controller-ur5", policy))
    with zenoh.open(session_config([endpoint], [], options)) as session:
        yield endpoint, pki, session


def _client(endpoint: str, pki: CellPki, cn: str, config: CellConfig) -> zenoh.Session:
    options = SessionOptions("client", mutual_tls(pki.root, cn, CellPolicy.from_config(config)))
    return zenoh.open(session_config([], [endpoint], options))


def test_recorder_certificate_cannot_publish_an_override(
    cell_config: CellConfig, controller: tuple[str, CellPki, zenoh.Session]
) -> None:
    endpoint, pki, controller_session = controller
    cell = cell_config.cell
    heard = _Heard(threading.Lock(), [])
    controller_session.declare_subscriber(keys.robot_override(cell, "ur5"), heard.on_sample)
    with (
        _client(endpoint, pki, RECORDER, cell_config) as recorder,
        _client(endpoint, pki, "gateway", cell_config) as gw,
    ):
        forged_pub = recorder.declare_publisher(keys.robot_override(cell, "ur5"))
        genuine_pub = gw.declare_publisher(keys.robot_override(cell, "ur5"))
        for i in range(50):
            forged_pub.put(to_payload(Override(robot="ur5", seq=FORGED_SEQ + i, stamp_ns=time.time_ns(), delta=1.0)))
            genuine_pub.put(to_payload(Override(robot="ur5", seq=i, stamp_ns=time.time_ns(), delta=0.0)))
        wait_for(lambda: len([o for o in heard.overrides() if o.seq < FORGED_SEQ]) == 50, 10.0, "the gateway's puts")
    assert [o.seq for o in heard.overrides() if o.seq >= FORGED_SEQ] == [], "a recorder's override got through"


def test_recorder_certificate_reads_the_cell(
    cell_config: CellConfig, controller: tuple[str, CellPki, zenoh.Session]
) -> None:
    endpoint, pki, controller_session = controller
    heard = _Heard(threading.Lock(), [])
    state_key = keys.robot_state(cell_config.cell, "ur5")
    with _client(endpoint, pki, RECORDER, cell_config) as recorder:
        recorder.declare_subscriber(state_key, heard.on_sample)
        publisher = controller_session.declare_publisher(state_key)

        def heard_some() -> bool:
            publisher.put(b'{"probe": true}')
            with heard.lock:
                return bool(heard.payloads)

        wait_for(heard_some, 10.0, "a joint state at the recorder")
