"""ABB Robot Web Services over the simulated link: polls of three requests on one keep-alive connection.

A poll every ``poll_rate_hz`` of three requests in sequence (speed ratio, execution state, joint target), answered with
the documents of :mod:`controller_emu.rws_face` and parsed by :mod:`hrc_devices.controllers.abb_rws.client` (q printed
``.7g`` in degrees, no velocities: the bridge differentiates q). A write is the speed ratio as an integer percent
rounded down (:func:`hrc_devices.controllers.abb_rws.client.speed_ratio_pct`), a POST whose 204 returns after a round
trip. Reads and writes share the one connection (the interface holds a lock), so a write waits for the request in
progress and a poll for a write; each request takes the latency twice (request, answer).
"""

from __future__ import annotations

import json
from typing import Any

from controller_emu.rws_face import execution_document, jointtarget_document, speedratio_document
from hrc_contract.config import AbbRwsInterfaceConfig
from hrc_devices.controllers.abb_rws.client import (
    parse_execution_state,
    parse_joint_target,
    parse_speed_ratio,
    reading_of,
    speed_ratio_pct,
)
from hrc_devices.controllers.vendor import VendorError
from hrc_tools.sim.exchanges.base import ExchangeHost, VendorLink
from hrc_tools.sim.links import NS_PER_S

__all__ = ["DEFAULT_LINK", "RwsExchange"]

DEFAULT_LINK = VendorLink(0.002)
"""Assumed, not measured: 2 ms each way, so an RWS request takes 4 ms (RWS's latency is not published and must be
measured on the controller; a loaded IRC5 may be much slower)."""

_RWS_BASE = "http://controller"
"""The base URL of the simulated RWS documents (their links are not followed)."""

_FOLLOWING = {"ratio": "execution", "execution": "jointtarget"}
"""A poll's requests, each sent when the one before is answered."""


class RwsExchange:
    """RWS between a bridge and the emulated controller's face (the module docstring)."""

    def __init__(self, interface: AbbRwsInterfaceConfig, host: ExchangeHost, link: VendorLink | None) -> None:
        self._host = host
        self._latency_ns = round((link or DEFAULT_LINK).latency_s * NS_PER_S)
        self._period_ns = round(NS_PER_S / interface.poll_rate_hz)
        self._connection_free_ns = 0  # the one HTTP connection is busy until then
        self._poll: dict[str, Any] = {}
        host.face.value = 1.0  # an IRC5 starts at 100 %

    def start(self, reader_phase_ns: int) -> None:
        self._host.push(reader_phase_ns % max(self._period_ns, 1), "poll")

    def write(self, value: float, t_ns: int) -> None:
        self._request("write", t_ns, speed_ratio_pct(value) / 100.0)

    def handle(self, kind: str, data: Any, t_ns: int) -> None:
        if kind == "poll":
            self._poll = {"due_ns": t_ns + self._period_ns}
            self._request("ratio", t_ns)
        elif kind == "serve":
            self._serve(data, t_ns)
        else:
            self._reply(data, t_ns)

    def _request(self, what: str, want_ns: int, value: float | None = None) -> None:
        """One request: it waits for the connection, is served one latency later and answered one after that."""
        start_ns = max(want_ns, self._connection_free_ns)
        self._connection_free_ns = start_ns + 2 * self._latency_ns
        self._host.push(start_ns + self._latency_ns, "serve", (what, value))
        self._host.push(start_ns + 2 * self._latency_ns, "reply", (what, value))

    def _serve(self, request: tuple[str, float | None], t_ns: int) -> None:
        """The controller answers a request with its state at ``t_ns`` (a write takes effect now)."""
        host = self._host
        what, value = request
        if what == "write":
            host.face.apply(host.node, host.node.robot, float(value or 0.0), host.clocks(t_ns))
            return
        state = host.node.state if host.latest is None else host.latest.state
        if what == "ratio":
            document = speedratio_document(_RWS_BASE, round(host.face.value * 100))
        elif what == "execution":
            document = execution_document(_RWS_BASE, state.mode)
        else:
            q_rad, truth = host.node.trajectory.sample(state.tau_s)
            self._poll["truth"] = truth
            document = jointtarget_document(_RWS_BASE, tuple(float(q) for q in q_rad))
        self._poll[what] = json.dumps(document).encode()

    def _reply(self, request: tuple[str, float | None], t_ns: int) -> None:
        host = self._host
        what, value = request
        if what == "write":  # the 204: the shell calls on_written now, and its writer is free again
            host.written(float(value or 0.0), t_ns)
            return
        if what in _FOLLOWING:
            self._request(_FOLLOWING[what], t_ns)
            return
        poll = self._poll
        host.push(max(poll["due_ns"], t_ns), "poll")
        try:
            ratio_pct = parse_speed_ratio(poll["ratio"])
            execution = parse_execution_state(poll["execution"])
            q_rad = parse_joint_target(poll["jointtarget"], host.node.trajectory.n_joints)
        except VendorError as exc:
            host.core.count_rejected(exc.reason)
            return
        host.reading(reading_of(ratio_pct, execution, q_rad, host.clocks(t_ns)), poll["truth"], t_ns)
