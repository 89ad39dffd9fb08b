"""JSON Schemas of the contract (`docs/contract.md`), generated from its pydantic models.

    .venv/bin/python -m hrc_contract.contract --write docs/schemas   # (re)write one <name>.schema.json per model
    .venv/bin/python -m hrc_contract.contract --check docs/schemas   # exit 1 if the files differ from the models

The models are the source of truth: the wire messages (:mod:`hrc_contract.messages`) and the status and REST
responses (:mod:`hrc_contract.status_models`). ``tests/test_contract.py`` runs the check, so a model changed
without regenerating the schemas fails the tests.
"""

from __future__ import annotations

import argparse
import difflib
import json
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from hrc_contract.messages import Humans, JointCommand, JointState, Override, TrackReset
from hrc_contract.status_models import (
    EffectiveConfig,
    ErrorResponse,
    EventsResponse,
    GatewayStatus,
    Health,
    NotReadyResponse,
    Ready,
    RobotStatusResponse,
)

PROG = "python -m hrc_contract.contract"
# relative to the current directory: the writer runs from the checkout (the schemas are part of the docs)
DEFAULT_DIR = Path("docs") / "schemas"
SUFFIX = ".schema.json"
JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
DIFF_LINES = 12
"""Lines of unified diff shown per differing file by ``--check``."""

MODELS: Mapping[str, type[BaseModel]] = {
    # wire messages (Zenoh)
    "joint_state": JointState,
    "humans": Humans,
    "override": Override,
    "joint_command": JointCommand,
    "track_reset": TrackReset,
    # the status document (Zenoh hrc/<cell>/gateway/status and GET /api/v1/status)
    "gateway_status": GatewayStatus,
    # REST responses
    "robot_status": RobotStatusResponse,
    "effective_config": EffectiveConfig,
    "health": Health,
    "ready": Ready,
    "not_ready": NotReadyResponse,
    "error": ErrorResponse,
    "events": EventsResponse,
}
"""File name (without :data:`SUFFIX`) → model."""


def schema_of(name: str, model: type[BaseModel]) -> dict[str, Any]:
    """The JSON Schema of what a producer sends: ``model`` in serialisation mode.

    A wire message must carry its ``schema`` string (``parse_message`` rejects it otherwise), although the
    model fills it in by default: the schema lists it as required.
    """
    schema = model.model_json_schema(mode="serialization")
    properties = schema.get("properties", {})
    required: list[str] = schema.setdefault("required", [])
    if "schema" in properties and "schema" not in required:
        required.insert(0, "schema")
    return {"$schema": JSON_SCHEMA_DIALECT, "$id": f"{name}{SUFFIX}", **schema}


def render(schema: Mapping[str, Any]) -> str:
    """The file text of one schema: 2-space indented JSON, UTF-8 characters as they are, final newline."""
    return json.dumps(schema, indent=2, ensure_ascii=False) + "\n"


def expected_files() -> dict[str, str]:
    """File name → text, for every model of the contract."""
    return {f"{name}{SUFFIX}": render(schema_of(name, model)) for name, model in MODELS.items()}


def write_schemas(directory: Path) -> list[str]:
    """Write every schema to ``directory`` (created if needed) and remove schema files of no model.

    Returns:
        The files written or removed, with what was done.
    """
    directory.mkdir(parents=True, exist_ok=True)
    expected = expected_files()
    done = []
    for file_name, text in expected.items():
        path = directory / file_name
        if not path.is_file() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
            done.append(f"wrote {file_name}")
    for path in sorted(directory.glob(f"*{SUFFIX}")):
        if path.name not in expected:
            path.unlink()
            done.append(f"removed {path.name} (no model)")
    return done


def check_schemas(directory: Path) -> list[str]:
    """How the schema files in ``directory`` differ from the models (empty: up to date)."""
    expected = expected_files()
    problems = []
    for file_name, text in expected.items():
        path = directory / file_name
        if not path.is_file():
            problems.append(f"missing: {file_name}")
            continue
        actual = path.read_text(encoding="utf-8")
        if actual != text:
            diff = list(
                difflib.unified_diff(
                    actual.splitlines(),
                    text.splitlines(),
                    f"{file_name} (on disk)",
                    f"{file_name} (from the model)",
                    lineterm="",
                    n=1,
                )
            )
            shown = "\n".join(f"    {line}" for line in diff[:DIFF_LINES])
            more = f"\n    ... ({len(diff) - DIFF_LINES} more diff lines)" if len(diff) > DIFF_LINES else ""
            problems.append(f"differs: {file_name}\n{shown}{more}")
    for path in sorted(directory.glob(f"*{SUFFIX}")) if directory.is_dir() else []:
        if path.name not in expected:
            problems.append(f"no model: {path.name}")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog=PROG, description="JSON Schemas of the contract's messages and responses, from the pydantic models."
    )
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument(
        "--write", nargs="?", const=str(DEFAULT_DIR), metavar="DIR", help=f"write the schemas (default {DEFAULT_DIR})"
    )
    action.add_argument(
        "--check",
        nargs="?",
        const=str(DEFAULT_DIR),
        metavar="DIR",
        help="exit 1 if the schema files differ from the models",
    )
    args = parser.parse_args(argv)
    if args.write is not None:
        done = write_schemas(Path(args.write))
        sys.stdout.write("".join(f"{line}\n" for line in done) or f"{len(MODELS)} schemas up to date\n")
        return 0
    directory = Path(args.check)
    problems = check_schemas(directory)
    if not problems:
        sys.stdout.write(f"{len(MODELS)} schemas in {directory} match the models\n")
        return 0
    sys.stderr.write(
        f"{PROG}: {len(problems)} schema file(s) in {directory} do not match the models:\n"
        + "".join(f"  {problem}\n" for problem in problems)
        + f"regenerate them: .venv/bin/{PROG} --write {directory}\n"
    )
    return 1


if __name__ == "__main__":
    sys.exit(main())
