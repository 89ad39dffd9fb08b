"""The contract (docs/contract.md) against the code: the schema files are the models' schemas, every example in the
document is valid, and every fault code and rejection reason the code can emit is in the document's tables."""

from __future__ import annotations

import ast
import json
import re
from pathlib import Path
from typing import get_args

import jsonschema_rs  # comes with schemathesis (dev dependency)
import pytest
import support.status_examples as ex
from support.paths import REPO_ROOT

from gateway.inputs import fault_code
from hrc_contract import contract
from hrc_contract.messages import JointState
from hrc_contract.status_models import ControllerMode, ZoneName
from hrc_contract.vocabulary import Zone
from hrc_devices.robots.time_scaling import Rejection

CONTRACT = REPO_ROOT / "docs" / "contract.md"
EMITTING_SOURCES = [
    "gateway/core.py",
    "gateway/delay.py",
    "gateway/inputs.py",
    "gateway/node.py",
    "gateway/main.py",
    "hrc_contract/humans.py",
    "hrc_contract/messages.py",
]
"""Where the gateway's fault codes and rejection reasons are written."""
COUNTING_CALLS = {"_reject": 1, "_count": 1, "count_rejection": 1, "MessageError": 0}
"""Calls that count a rejection, and the position of the reason among their arguments."""
FAULT_CALLS = {"Fault", "TopicFault"}
REASON_RETURNING = {
    "_joint_state_problem",
    "implausible_reason",
    "implausible_detail",
    "_implausible_person",
    "order",
    "fault_code",
}
"""Functions whose string results are reasons (or, for ``fault_code``, codes)."""


def _section(title: str) -> str:
    text = CONTRACT.read_text(encoding="utf-8")
    match = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert match is not None, f"no section '## {title}' in {CONTRACT}"
    return match.group(1)


def _table_rows(title: str) -> list[list[str]]:
    """The rows of the first table of a section, as cells (header and rule excluded)."""
    rows: list[str] = []
    for line in _section(title).splitlines():
        if line.startswith("|"):
            rows.append(line)
        elif rows:
            break
    return [[cell.strip() for cell in row.strip("|").split("|")] for row in rows[2:]]


def _first_code(cell: str) -> str:
    match = re.match(r"`([^`]+)`", cell)
    assert match is not None, f"no `code` at the start of table cell {cell!r}"
    return match.group(1)


def documented_fault_codes() -> set[str]:
    return {_first_code(row[0]) for row in _table_rows("Fault codes")}


def documented_reasons() -> set[str]:
    return {_first_code(row[0]) for row in _table_rows("Rejection reasons")}


def _name(func: ast.expr) -> str | None:
    if isinstance(func, ast.Name):
        return func.id
    if isinstance(func, ast.Attribute):
        return func.attr
    return None


def _strings(node: ast.AST | None) -> list[str]:
    """String constants of an expression: itself, the first element of a tuple, the operands of ``a or "b"`` and
    of ``"a" if c else "b"``."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Tuple) and node.elts:  # return "reason", "detail"
        return _strings(node.elts[0])
    if isinstance(node, ast.BoolOp):
        return [s for value in node.values for s in _strings(value)]
    if isinstance(node, ast.IfExp):
        return [*_strings(node.body), *_strings(node.orelse)]
    return []


def emitted_codes_and_reasons(path: Path) -> tuple[set[str], set[str]]:
    """(fault codes, rejection reasons) written as literals in one source file."""
    codes: set[str] = set()
    reasons: set[str] = set()
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            name = _name(node.func)
            if name in FAULT_CALLS and node.args:
                codes.update(_strings(node.args[0]))
            if name in COUNTING_CALLS and len(node.args) > COUNTING_CALLS[name]:
                reasons.update(_strings(node.args[COUNTING_CALLS[name]]))
            codes.update(s for kw in node.keywords if kw.arg == "code" for s in _strings(kw.value))
        elif isinstance(node, ast.Subscript) and _name(node.value) == "_rejected" and isinstance(node.slice, ast.Tuple):
            reasons.update(s for elt in node.slice.elts[1:] for s in _strings(elt))
        elif isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "reason" for t in node.targets):
            reasons.update(_strings(node.value))
        elif isinstance(node, ast.FunctionDef) and node.name in REASON_RETURNING:
            found = {s for ret in ast.walk(node) if isinstance(ret, ast.Return) for s in _strings(ret.value)}
            (codes if node.name == "fault_code" else reasons).update(found)
    return codes, reasons


# -- schema files ---------------------------------------------------------------------------------------------


def test_the_schema_files_are_the_models_schemas() -> None:
    problems = contract.check_schemas(REPO_ROOT / contract.DEFAULT_DIR)
    assert problems == [], "\n".join(problems) + "\nregenerate: .venv/bin/python -m hrc_contract.contract --write"


def test_check_reports_a_stale_a_missing_and_an_extra_file_and_write_repairs_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert contract.main(["--write", str(tmp_path)]) == 0
    assert contract.main(["--check", str(tmp_path)]) == 0
    status = tmp_path / "gateway_status.schema.json"
    status.write_text(status.read_text().replace('"zone"', '"zones"', 1))
    (tmp_path / "override.schema.json").unlink()
    (tmp_path / "old.schema.json").write_text("{}\n")
    capsys.readouterr()
    assert contract.main(["--check", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "differs: gateway_status.schema.json" in err
    assert re.search(r'^\s*-\s*"zones": \{$', err, re.MULTILINE), err  # the diff shows what changed
    assert "missing: override.schema.json" in err
    assert "no model: old.schema.json" in err
    assert "--write" in err
    assert contract.main(["--write", str(tmp_path)]) == 0
    assert contract.main(["--check", str(tmp_path)]) == 0
    assert not (tmp_path / "old.schema.json").exists()


def test_a_wire_message_schema_requires_its_schema_string() -> None:
    for name in ("joint_state", "humans", "override"):
        schema = contract.schema_of(name, contract.MODELS[name])
        assert "schema" in schema["required"], name


def test_the_schema_files_accept_a_real_status_and_refuse_an_unknown_field() -> None:
    """The files work for a consumer without pydantic (any JSON Schema 2020-12 validator)."""
    schema = json.loads((REPO_ROOT / contract.DEFAULT_DIR / "gateway_status.schema.json").read_text())
    validator = jsonschema_rs.Draft202012Validator(schema)
    doc = json.loads(ex.gateway_status(ur5=ex.near_robot_status()).model_dump_json())
    assert validator.is_valid(doc)
    doc["robots"]["ur5"]["speed"] = 1.0
    assert not validator.is_valid(doc)


# -- the document ----------------------------------------------------------------------------------------------


def test_every_example_in_the_contract_is_valid() -> None:
    text = CONTRACT.read_text(encoding="utf-8")
    examples = re.findall(r"<!-- example: (\w+) -->\n```json\n(.*?)\n```", text, re.DOTALL)
    assert {name for name, _ in examples} >= {"joint_state", "humans", "override", "gateway_status", "robot_status"}
    for name, body in examples:
        assert name in contract.MODELS, f"example of unknown model {name!r}"
        contract.MODELS[name].model_validate_json(body)


def test_the_contract_links_every_schema_file() -> None:
    text = CONTRACT.read_text(encoding="utf-8")
    for file_name in contract.expected_files():
        assert f"(schemas/{file_name})" in text, file_name


def test_every_fault_code_and_rejection_reason_the_code_emits_is_in_the_tables() -> None:
    codes: set[str] = set()
    reasons: set[str] = set()
    for source in EMITTING_SOURCES:
        found_codes, found_reasons = emitted_codes_and_reasons(REPO_ROOT / source)
        codes |= found_codes
        reasons |= found_reasons
    assert {"tracker_stale", "joint_state_missing", "override_path_unconfirmed"} <= codes  # the scan finds them
    assert {"not_json", "unknown_robot", "name_mismatch"} <= reasons
    assert codes - documented_fault_codes() == set(), "fault codes missing from docs/contract.md, '## Fault codes'"
    assert reasons - documented_reasons() == set(), "reasons missing from docs/contract.md, '## Rejection reasons'"


def test_the_scan_finds_a_new_code_and_a_new_reason(tmp_path: Path) -> None:
    """The teeth of the test above: a code or reason added in the usual ways is found."""
    source = tmp_path / "new.py"
    source.write_text(
        "def f(self, topic, received):\n"
        '    faults = [Fault("brand_new_fault", "why")]\n'
        '    self._reject(topic, "brand_new_reason", "", received)\n'
        '    self._rejected[(topic, "another_reason")] += 1\n'
    )
    codes, reasons = emitted_codes_and_reasons(source)
    assert codes == {"brand_new_fault"}
    assert reasons == {"brand_new_reason", "another_reason"}
    assert "brand_new_fault" not in documented_fault_codes()


def test_the_rejection_table_names_the_fault_each_reason_raises() -> None:
    kinds = {"both": ("joint_state", "tracker"), "robot": ("joint_state",), "tracker": ("tracker",)}
    checked = 0
    for row in _table_rows("Rejection reasons"):
        reason, topics, fault = _first_code(row[0]), row[1], row[2]
        if fault == "none":
            continue
        for kind in kinds[topics]:
            assert fault_code(kind, reason) == _first_code(fault).replace("<kind>", kind), reason  # type: ignore[arg-type]
            checked += 1
    assert checked >= 20


def test_every_fault_code_a_rejection_can_raise_is_in_the_fault_table() -> None:
    rows = _table_rows("Rejection reasons")
    raised = {
        _first_code(row[2]).replace("<kind>", kind)
        for row in rows
        if row[2] != "none"
        for kind in ("joint_state", "tracker")
        if row[1] == "both" or (row[1] == "robot") == (kind == "joint_state")
    }
    assert raised - documented_fault_codes() == set()


def test_the_controller_emulator_reasons_are_documented() -> None:
    text = _section("Rejection reasons")
    for reason in get_args(Rejection):
        assert f"`{reason}`" in text, reason


def test_zone_and_mode_names_are_the_codes() -> None:
    assert set(get_args(ZoneName)) == {zone.value for zone in Zone}
    assert set(get_args(ControllerMode)) == set(get_args(JointState.model_fields["mode"].annotation))


def test_the_zone_names_of_the_status_are_the_zones() -> None:
    from typing import get_args

    from hrc_contract.vocabulary import Zone, ZoneName

    assert get_args(ZoneName) == tuple(zone.value for zone in Zone)
