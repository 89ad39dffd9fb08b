"""Where a program finds its cell file and its state folder: given, from the environment, or in the checkout.

Never derived from ``__file__``: an installed package knows nothing of a checkout. In this order:

1. the command line (``--config``; ``--pki-dir`` for the PKI);
2. the environment: ``HRC_CONFIG`` (the cell file), ``HRC_STATE_DIR`` (the state folder);
3. the checkout, when the program runs inside one (an editable install used from its folder): the nearest
   directory at or above the current working directory holding a ``pyproject.toml`` whose project name is
   ``hrc-gateway``; its ``configs/cell.toml`` and ``.state/``.

Otherwise :class:`NotFoundError` (a :class:`~hrc_contract.config.ConfigError`, so the programs exit 2) names
every place it looked.
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Mapping
from pathlib import Path

from hrc_contract.config import ConfigError

CONFIG_ENV_VAR = "HRC_CONFIG"
STATE_DIR_ENV_VAR = "HRC_STATE_DIR"
PROJECT_NAME = "hrc-gateway"
CHECKOUT_CELL = Path("configs") / "cell.toml"
CHECKOUT_STATE = Path(".state")


class NotFoundError(ConfigError):
    """A file or folder a program needs was neither given nor found; the message names where it looked."""


def _project_name(pyproject: Path) -> str | None:
    try:
        project = tomllib.loads(pyproject.read_text()).get("project", {})
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    name = project.get("name") if isinstance(project, dict) else None
    return name if isinstance(name, str) else None


def find_checkout(cwd: Path | None = None) -> Path | None:
    """The hrc-gateway checkout at or above ``cwd`` (default: the current working directory), or None."""
    here = (Path.cwd() if cwd is None else cwd).resolve()
    for directory in (here, *here.parents):
        pyproject = directory / "pyproject.toml"
        if pyproject.is_file() and _project_name(pyproject) == PROJECT_NAME:
            return directory
    return None


def _checkout_place(relative: Path, cwd: Path | None) -> str:
    here = (Path.cwd() if cwd is None else cwd).resolve()
    return f"{relative} of an {PROJECT_NAME} checkout at or above {here} (none found)"


def find_cell_config(
    path: Path | str | None = None, environ: Mapping[str, str] | None = None, cwd: Path | None = None
) -> Path:
    """The cell file: ``path`` if given, else ``$HRC_CONFIG``, else the checkout's ``configs/cell.toml``.

    Raises:
        NotFoundError: none of them; the message lists the places looked at.
    """
    if path is not None:
        return Path(path)
    given = (os.environ if environ is None else environ).get(CONFIG_ENV_VAR)
    if given:
        return Path(given)
    checkout = find_checkout(cwd)
    if checkout is not None and (checkout / CHECKOUT_CELL).is_file():
        return checkout / CHECKOUT_CELL
    place = str(checkout / CHECKOUT_CELL) + " (missing)" if checkout else _checkout_place(CHECKOUT_CELL, cwd)
    raise NotFoundError(f"no cell file given; looked at --config, ${CONFIG_ENV_VAR} (unset) and {place}")


def find_state_dir(environ: Mapping[str, str] | None = None, cwd: Path | None = None) -> Path:
    """The state folder (PKI, recordings): ``$HRC_STATE_DIR``, else the checkout's ``.state/`` (may not exist yet).

    Raises:
        NotFoundError: neither; the message lists the places looked at.
    """
    given = (os.environ if environ is None else environ).get(STATE_DIR_ENV_VAR)
    if given:
        return Path(given)
    checkout = find_checkout(cwd)
    if checkout is not None:
        return checkout / CHECKOUT_STATE
    raise NotFoundError(
        f"no state folder; looked at ${STATE_DIR_ENV_VAR} (unset) and {_checkout_place(CHECKOUT_STATE, cwd)}"
    )
