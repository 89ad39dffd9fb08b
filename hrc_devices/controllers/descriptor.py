"""What the programs know of a vendor: its speed input, what its interface config gives the bridge, and the
:class:`Vendor` descriptor of a closed controller's vendor (registered in
:data:`hrc_devices.controllers.registry.VENDORS`) or the :class:`OpenVendor` descriptor of an open controller's
(registered in :data:`hrc_devices.controllers.registry.OPEN_VENDORS`); one per vendor folder.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar, runtime_checkable

from hrc_devices.controllers.vendor import OpenVendorInterface, VendorInterface

__all__ = ["BridgedConfig", "OpenBridgedConfig", "OpenVendor", "SpeedInput", "Vendor"]


@dataclass(frozen=True)
class SpeedInput:
    """A vendor's speed input.

    Attributes:
        floor: the smallest value the input is written with; below it the bridge writes ``stop`` [1].
        step: the resolution, rounded down to (None: continuous) [1].
        stop: what is written below the floor, and why (for the documentation and the log).
        dither_step: d, how far below δ a write moves to differ from the values it must not repeat (the bridge's
            module docstring, "Every write provable"); a multiple of ``step`` [1].
    """

    floor: float
    step: float | None
    stop: str
    dither_step: float


@runtime_checkable
class BridgedConfig(Protocol):
    """What every vendor's interface config (``hrc_contract.config``) gives the bridge besides its address."""

    @property
    def kind(self) -> str: ...
    @property
    def watchdog_s(self) -> float: ...
    @property
    def read_timeout_s(self) -> float: ...
    @property
    def write_rate_hz(self) -> float: ...
    @property
    def rise_time_s(self) -> float: ...


@runtime_checkable
class OpenBridgedConfig(Protocol):
    """What an open controller's interface config (``hrc_contract.config``) gives the bridge besides its address."""

    @property
    def kind(self) -> str: ...
    @property
    def watchdog_s(self) -> float: ...
    @property
    def read_timeout_s(self) -> float: ...
    @property
    def extrapolate_s(self) -> float: ...


ConfigT = TypeVar("ConfigT")


def _no_environment(config: Any, env: dict[str, str]) -> None:
    """A vendor whose bridge needs no environment variable."""


def _zero(config: Any) -> float:
    return 0.0


@dataclass(frozen=True)
class Vendor(Generic[ConfigT]):
    """Everything the programs know of one vendor: one per vendor folder (``ur_rtde/``, ``abb_rws/``), registered
    by kind in :data:`hrc_devices.controllers.registry.VENDORS`. The programs ask it; none of them names a vendor.

    Attributes:
        kind: the cell file's ``[robots.<name>.interface] kind`` (the config class's ``kind`` literal).
        config: the contract's interface config class (``hrc_contract.config``) of this kind.
        speed_input: the controller's speed input (the bridge quantises and dithers on it).
        interface: ``(config, n_joints, environ)`` → the vendor interface, not yet connected. Raises
            :class:`~hrc_contract.config.ConfigError` when the configuration cannot be served.
        emulator_args: ``config`` → the controller emulator's options that serve this vendor's face (``hrc-cell``).
            Raises :class:`~hrc_contract.config.ConfigError` when the emulator cannot serve it.
        environment: ``(config, env)``: sets, where unset, what the bridge needs in its environment when the
            controller is the emulator (``hrc-cell``; ABB's password variable).
        sample_jitter_s: ``config`` → how far the controller's sampling of q may be from the receive times [s]
            (0: the controller stamps its readings).
        poll_interval_s: ``config`` → the reader's interval between polls [s] (0: the controller pushes readings).
        sim_interface: the cell file's interface table for ``hrc-sweep --interface KIND`` (the shipped cells').
    """

    kind: str
    config: type[ConfigT]
    speed_input: SpeedInput
    interface: Callable[[ConfigT, int, Mapping[str, str]], VendorInterface]
    emulator_args: Callable[[ConfigT], list[str]]
    sim_interface: Mapping[str, Any]
    environment: Callable[[ConfigT, dict[str, str]], None] = field(default=_no_environment)
    sample_jitter_s: Callable[[ConfigT], float] = field(default=_zero)
    poll_interval_s: Callable[[ConfigT], float] = field(default=_zero)


@dataclass(frozen=True)
class OpenVendor(Generic[ConfigT]):
    """Everything the programs know of one *open* controller's vendor (joint references in, joint feedback out):
    one per vendor folder (``abb_egm/``), registered by kind in
    :data:`hrc_devices.controllers.registry.OPEN_VENDORS`, never among the closed vendors (a closed cell is not
    offered it).

    Attributes:
        kind: the cell file's ``[robots.<name>.interface] kind`` (the config class's ``kind`` literal).
        config: the contract's interface config class (``hrc_contract.config``) of this kind.
        interface: ``(config, n_joints)`` → the vendor interface, not yet connected.
        emulator_args: ``config`` → the controller emulator's options that serve this vendor's face (``hrc-cell``).
        velocity_source: how the bridge gets joint velocities, for the documentation and the status (EGM: q
            differenced over the controller's own stamps).
    """

    kind: str
    config: type[ConfigT]
    interface: Callable[[ConfigT, int], OpenVendorInterface]
    emulator_args: Callable[[ConfigT], list[str]]
    velocity_source: str
