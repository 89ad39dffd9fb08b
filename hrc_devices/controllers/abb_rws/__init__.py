"""ABB over Robot Web Services 1.0: HTTP Digest (:mod:`.http_digest`) and the bridge's client (:mod:`.client`); the
controller emulator serves the face (``controller_emu.rws_face``)."""

from __future__ import annotations

from collections.abc import Mapping
from urllib.parse import urlsplit

from hrc_contract.config import AbbRwsInterfaceConfig, ConfigError
from hrc_devices.controllers.abb_rws.client import AbbRwsInterface
from hrc_devices.controllers.descriptor import SpeedInput, Vendor
from hrc_devices.controllers.vendor import VendorInterface

__all__ = ["EMULATOR_RWS_PASSWORD", "VENDOR", "client", "http_digest"]

SPEED_INPUT = SpeedInput(
    floor=0.01,
    step=0.01,
    stop="speed ratio 0 %: RWS accepts 0..100 (integer percent, rounded down, so any δ < 1 % is 0 %)",
    dither_step=0.01,
)

EMULATOR_RWS_PASSWORD = "robotics"
"""The RWS password the controller emulator serves, as an ABB controller is shipped (user ``Default User``)."""


def _interface(config: AbbRwsInterfaceConfig, n_joints: int, environ: Mapping[str, str]) -> VendorInterface:
    password = environ.get(config.password_env)
    if password is None:
        raise ConfigError(
            f"environment variable {config.password_env} (interface.password_env) is not set; allowed: set it "
            "to the RWS password"
        )
    url = urlsplit(config.url)
    if url.scheme != "http" or url.hostname is None:
        raise ConfigError(
            f"interface.url = {config.url!r}: this bridge speaks RWS 1.0 over plain HTTP only; allowed: "
            "http://HOST[:PORT] (RWS 2.0 over HTTPS is not supported yet)"
        )
    return AbbRwsInterface(
        url.hostname,
        url.port or 80,
        config.user,
        password,
        n_joints=n_joints,
        timeout_s=config.read_timeout_s,
    )


def _emulator_args(config: AbbRwsInterfaceConfig) -> list[str]:
    url = urlsplit(config.url)
    if url.scheme != "http" or url.hostname is None:
        raise ConfigError(
            f"interface.url = {config.url!r}: the controller emulator serves RWS 1.0 over plain HTTP only; "
            "allowed: http://HOST[:PORT]"
        )
    return ["--rws", f"{url.hostname}:{url.port or 80}"]


def _environment(config: AbbRwsInterfaceConfig, env: dict[str, str]) -> None:
    env.setdefault(config.password_env, EMULATOR_RWS_PASSWORD)


VENDOR = Vendor(
    kind="abb_rws",
    config=AbbRwsInterfaceConfig,
    speed_input=SPEED_INPUT,
    interface=_interface,
    emulator_args=_emulator_args,
    sim_interface={"kind": "abb_rws", "url": "http://127.0.0.3:8081", "password_env": "HRC_RWS_PASSWORD"},
    environment=_environment,
    sample_jitter_s=lambda config: config.sample_jitter_s,
    poll_interval_s=lambda config: 1.0 / config.poll_rate_hz,
)
