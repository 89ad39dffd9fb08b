"""Loading the cell file: TOML, robot model files, programs and URDFs, validated into a CellConfig.

The models are :mod:`hrc_contract.config`; where the file is found, :mod:`hrc_runtime.locate`.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from hrc_contract.config import CellConfig, ConfigError
from hrc_runtime.locate import find_cell_config


def example_robot_data_dir() -> Path:
    """Folder of the URDFs shipped by the ``example-robot-data`` package (it has no Python module)."""
    import pinocchio  # heavy: imported only when a URDF path must be resolved

    return Path(pinocchio.__file__).resolve().parents[4] / "share" / "example-robot-data" / "robots"


def read_toml(path: Path) -> dict[str, Any]:
    """A TOML file as a dictionary. Raises ConfigError (one line) when missing or not TOML."""
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def _resolve(base: Path, relative: str) -> Path:
    return (base / relative).resolve()


def resolve_urdf(urdf: str, config_dir: Path) -> Path:
    """An absolute URDF path: as given, relative to the config folder, or inside example-robot-data."""
    given = Path(urdf)
    candidates = [given] if given.is_absolute() else [config_dir / given, example_robot_data_dir() / given]
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    raise ConfigError(
        f"URDF {urdf!r} not found; allowed: an absolute path, a path relative to {config_dir}, "
        f"or a path inside {example_robot_data_dir()}"
    )


_RANGE_ERRORS = frozenset({"greater_than", "greater_than_equal", "less_than", "less_than_equal", "finite_number"})
"""Pydantic error types whose message says what is allowed but not what was given."""


def one_line(exc: ValidationError, source: Path | str) -> str:
    """A pydantic validation error as one line: ``source: field: message; ...`` (at most three errors); a value
    out of range is quoted: ``field: Input should be less than or equal to 1 (given 3600.0)``."""
    parts = []
    for err in exc.errors()[:3]:
        where = ".".join(str(p) for p in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] in _RANGE_ERRORS:
            msg += f" (given {err['input']!r})"
        parts.append(f"{where}: {msg}" if where else msg)
    more = f" (and {exc.error_count() - 3} more)" if exc.error_count() > 3 else ""
    return f"{source}: " + "; ".join(parts) + more


def load_cell_config(path: Path | str | None = None) -> CellConfig:
    """Load and validate a cell file and the robot model files and programs it references.

    Raises:
        ConfigError: the file is missing, not TOML, or not a valid, safe configuration.
    """
    cell_path = find_cell_config(path)
    cell_path = cell_path.resolve()
    raw = read_toml(cell_path)
    config_dir = cell_path.parent
    robots_raw = raw.get("robots", {})
    if not isinstance(robots_raw, dict):
        raise ConfigError(f"{cell_path}: robots must be a table of robot names")
    for name, robot in robots_raw.items():
        if not isinstance(robot, dict):
            raise ConfigError(f"{cell_path}: robots.{name} must be a table")
        model_ref = robot.get("model")
        if isinstance(model_ref, str):
            model_path = _resolve(config_dir, model_ref)
            model = read_toml(model_path)
            if isinstance(model.get("urdf"), str):
                model["urdf"] = str(resolve_urdf(model["urdf"], model_path.parent))
            robot["model"] = model
        program_ref = robot.get("program")
        if isinstance(program_ref, str):
            program_path = _resolve(config_dir, program_ref)
            if not program_path.is_file():
                raise ConfigError(f"{cell_path}: robots.{name}.program: {program_path}: no such file")
            robot["program"] = str(program_path)
    raw["scenarios_dir"] = str(_resolve(config_dir, str(raw.get("scenarios_dir", "scenarios"))))
    safety = raw.get("safety")
    if isinstance(safety, dict) and isinstance(safety.get("pfl_body_regions"), str):  # a file: its [regions] read in
        safety["pfl_body_regions"] = read_toml(_resolve(config_dir, safety["pfl_body_regions"])).get("regions", {})
    try:
        return CellConfig.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(one_line(exc, cell_path)) from None
