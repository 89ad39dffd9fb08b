"""The vendor faces the emulator can serve, by the cell file's interface kind: the one place that lists them (as
:data:`hrc_devices.controllers.registry.VENDORS` lists the vendors a bridge reaches).

    faces = start_faces(FACES, asked, node, model)    # asked: {kind: the option's text}, e.g. {"ur_rtde": "127.0.0.2"}

Each face is one option of ``hrc-controller-emu`` (``--rtde HOST``, ``--rws HOST:PORT``, ``--egm HOST:PORT``), for
one kind of controller: a closed one's faces write its speed override, an open one's its joint references. While a
face serves a robot, its commands come only from that face and the emulator publishes nothing on the cell's state key
(the bridge publishes what it reads); the ground truth and the stats go out as always.

Adding a face: its module in ``controller_emu`` (a class with ``start``, ``on_cycle``, ``close`` and ``progress``) and
one :func:`register_face` line below; the vendor's ``emulator_args`` (its folder in ``hrc_devices/controllers``) then
names the option.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from controller_emu.egm_face import EgmFace
from controller_emu.rtde_face import RtdeFace
from controller_emu.rws_face import RwsFace
from hrc_contract.config import ConfigError
from hrc_devices.robots.model import RobotModel

__all__ = ["FACES", "Face", "VendorFace", "parse_host_port", "register_face", "start_faces"]


class VendorFace(Protocol):
    """A vendor's interface served by the emulator."""

    def start(self) -> None: ...

    def on_cycle(self, output: Any) -> None: ...

    def close(self) -> None: ...

    def progress(self) -> str:
        """What the face did, for the emulator's progress line (e.g. ``egm_sent=… egm_received=…``)."""
        ...


@dataclass(frozen=True)
class Face:
    """One vendor face of the emulator.

    Attributes:
        kind: the vendor's interface kind (the cell file's ``[robots.<name>.interface] kind``, or the vendor folder
            of a controller that has no bridge yet).
        option: the emulator's command-line option that serves it.
        metavar, help: for the option's help.
        control: the controller it belongs to: ``closed`` (a program and a speed override) or ``open`` (joint
            references every cycle).
        address: the option's text → the address :attr:`serve` takes. Raises :class:`ConfigError`.
        serve: ``(node, model, address)`` → the face, not started.
        describe: ``address`` → where it serves, for the log (e.g. ``RTDE 127.0.0.2:30004``).
        on_silence: an open controller's behaviour when the references stop (``keep_speed``: the Zenoh joint
            commands' default; ``hold_reference``: EGM's position mode); None for a closed one.
    """

    kind: str
    option: str
    metavar: str
    help: str
    control: Literal["closed", "open"]
    address: Callable[[str], Any]
    serve: Callable[[Any, RobotModel, Any], VendorFace]
    describe: Callable[[Any], str]
    on_silence: Literal["keep_speed", "hold_reference"] | None = None


FACES: dict[str, Face] = {}
"""Every face the emulator can serve, by kind."""


def register_face(face: Face) -> None:
    """Add ``face`` (a test's fake one too); its kind replaces one of the same name."""
    FACES[face.kind] = face


def parse_host_port(text: str, option: str, example: str) -> tuple[str, int]:
    """``HOST:PORT``.

    Raises:
        ConfigError: not HOST:PORT with a port in 1-65535 (the message names ``option`` and shows ``example``).
    """
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"{option} {text!r}; expected HOST:PORT with a port in 1-65535 (e.g. {example})")
    return host, int(port)


def start_faces(faces: Mapping[str, Face], asked: Mapping[str, Any], node: Any, model: RobotModel) -> list[VendorFace]:
    """Start the faces ``asked`` for (kind → address), in order; on a failure close those already started.

    Raises:
        ConfigError: a face cannot listen (or send) on its address, or cannot serve this robot.
    """
    started: list[VendorFace] = []
    try:
        for kind, address in asked.items():
            face = faces[kind].serve(node, model, address)
            try:
                face.start()
            except OSError as exc:
                raise ConfigError(f"{faces[kind].describe(address)}: cannot be served: {exc}") from None
            started.append(face)
    except ConfigError:
        for face in started:
            face.close()
        raise
    return started


def _host_port(option: str, example: str) -> Callable[[str], tuple[str, int]]:
    return lambda text: parse_host_port(text, option, example)


register_face(
    Face(
        kind="ur_rtde",
        option="--rtde",
        metavar="HOST",
        help="serve UR RTDE on HOST:30004; overrides only from its speed slider",
        control="closed",
        address=str,
        serve=lambda node, model, host: RtdeFace(node, host, model=model),
        describe=lambda host: f"RTDE {host}:30004",
    )
)
register_face(
    Face(
        kind="abb_rws",
        option="--rws",
        metavar="HOST:PORT",
        help="serve ABB RWS on HOST:PORT; overrides only from its ratio",
        control="closed",
        address=_host_port("--rws", "127.0.0.3:8080"),
        serve=lambda node, model, address: RwsFace(node, *address),
        describe=lambda address: f"RWS {address[0]}:{address[1]}",
    )
)
register_face(
    Face(
        kind="abb_egm",
        option="--egm",
        metavar="HOST:PORT",
        help='an open controller (control = "open") plays ABB EGM: EgmRobot every cycle to the PC at HOST:PORT, '
        "joint references only from its EgmSensor replies",
        control="open",
        address=_host_port("--egm", "127.0.0.1:6510"),
        serve=lambda node, model, address: EgmFace(node, *address),
        describe=lambda address: f"EGM (EgmRobot to {address[0]}:{address[1]})",
        on_silence="hold_reference",
    )
)
