"""Rules that keep the layout (issue 18): the installed names listed here, no checkout paths from ``__file__``, curated
``__all__``, one definition per public function name in a package, the documented exception tree."""

from __future__ import annotations

import ast
import importlib
import inspect
import io
import pkgutil
import re
import tokenize
from collections import Counter
from pathlib import Path

import pytest
from setuptools import find_packages
from support.paths import REPO_ROOT

from hrc_contract import errors
from hrc_contract.errors import HrcError
from hrc_devices.controllers.registry import VENDORS

PACKAGES = (
    "hrc_contract",
    "hrc_runtime",
    "hrc_devices",
    "gateway",
    "controller_emu",
    "controller_bridge",
    "tracker_emu",
    "hrc_tools",
)
# a program's or tool's entry points: one per program by design
ENTRY_NAMES = {"cli", "main"}


def _installed_files() -> list[Path]:
    return sorted(p for package in PACKAGES for p in (REPO_ROOT / package).rglob("*.py"))


def test_the_wheel_installs_the_listed_names_only() -> None:
    include = re.search(r"^include = \[(.*)\]$", (REPO_ROOT / "pyproject.toml").read_text(), flags=re.M)
    assert include is not None
    patterns = [p.strip().strip('"') for p in include.group(1).split(",")]
    found = find_packages(where=str(REPO_ROOT), include=patterns)
    assert {name.split(".")[0] for name in found} == set(PACKAGES)


def test_no_installed_module_reaches_a_checkout_folder_from_its_own_location() -> None:
    parent_walk = re.compile(r"Path\(__file__\)[^\n]*(\.parents\[|\.parent\.parent)")
    offenders = [str(p.relative_to(REPO_ROOT)) for p in _installed_files() if parent_walk.search(p.read_text())]
    assert offenders == []


@pytest.mark.parametrize("package", PACKAGES)
def test_every_package_init_has_a_curated_all(package: str) -> None:
    root = importlib.import_module(package)
    for info in [None, *pkgutil.walk_packages(root.__path__, f"{package}.")]:
        name = package if info is None else info.name
        if info is not None and not info.ispkg:
            continue
        module = importlib.import_module(name)
        exported = getattr(module, "__all__", None)
        assert isinstance(exported, list | tuple), f"{name}: no __all__"
        assert len(set(exported)) == len(exported), f"{name}: __all__ repeats a name"
        for item in exported:
            assert hasattr(module, item) or importlib.util.find_spec(f"{name}.{item}"), f"{name}.{item} missing"


@pytest.mark.parametrize("package", PACKAGES)
def test_no_public_function_name_is_defined_twice_in_a_package(package: str) -> None:
    names: Counter[str] = Counter()
    for path in (REPO_ROOT / package).rglob("*.py"):
        if "reference" in path.relative_to(REPO_ROOT).parts or path.name == "__main__.py":
            continue
        tree = ast.parse(path.read_text())
        names.update(
            node.name
            for node in tree.body
            if isinstance(node, ast.FunctionDef) and not node.name.startswith("_") and node.name not in ENTRY_NAMES
        )
    assert sorted(name for name, count in names.items() if count > 1) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_module_is_listed_in_its_package_all(package: str) -> None:
    unlisted = []
    root = importlib.import_module(package)
    for info in [None, *pkgutil.walk_packages(root.__path__, f"{package}.")]:
        name = package if info is None else info.name
        if info is not None and not info.ispkg:
            continue
        module = importlib.import_module(name)
        exported = set(getattr(module, "__all__", ()))
        unlisted += [
            f"{name}.{sub.name}"
            for sub in pkgutil.iter_modules(module.__path__)
            if not sub.name.startswith("_") and sub.name not in exported
        ]
    assert unlisted == []


def _imports_below_module_level(tree: ast.Module) -> list[ast.Import | ast.ImportFrom]:
    """Imports inside a function, a class or an ``if`` (``TYPE_CHECKING``): what hides an import circle."""
    top = {id(node) for node in tree.body if isinstance(node, ast.Import | ast.ImportFrom)}
    return [node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in top]


def test_no_module_imports_its_own_package_below_module_level() -> None:
    """An import of the same top package inside a function (or under ``TYPE_CHECKING``) hides a circle: none."""
    offenders = []
    for path in _installed_files():
        package = path.relative_to(REPO_ROOT).parts[0]
        for node in _imports_below_module_level(ast.parse(path.read_text())):
            names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
            if any(n == package or n.startswith(f"{package}.") for n in names):
                offenders.append(f"{path.relative_to(REPO_ROOT)}:{node.lineno}")
    assert offenders == []


def _vendor_places(kind: str) -> tuple[str, ...]:
    """Where a vendor's kind string and config class may appear: the contract, its folder, the registries (and the
    family's ``__all__``, which lists the folder by its name, the kind), its exchange in the simulated cell, and the
    emulator's registry of faces."""
    return (
        "hrc_contract/",
        f"hrc_devices/controllers/{kind}/",
        "hrc_devices/controllers/registry.py",
        "hrc_devices/controllers/__init__.py",
        f"hrc_tools/sim/exchanges/{kind}.py",
        "hrc_tools/sim/exchanges/__init__.py",
        "controller_emu/faces.py",
    )


def test_a_vendors_kind_and_config_class_appear_only_in_the_contract_its_folder_and_the_registries() -> None:
    offenders = []
    for path in _installed_files():
        rel = str(path.relative_to(REPO_ROOT))
        tokens = list(tokenize.generate_tokens(io.StringIO(path.read_text()).readline))
        for kind, vendor in VENDORS.items():
            if rel.startswith(_vendor_places(kind)):
                continue
            for tok in tokens:
                literal = tok.type == tokenize.STRING and tok.string.strip("\"'") == kind
                if literal or (tok.type == tokenize.NAME and tok.string == vendor.config.__name__):
                    offenders.append(f"{rel}:{tok.start[0]}: {tok.string}")
    assert offenders == []


def _all_subclasses(cls: type) -> set[type]:
    found = set(cls.__subclasses__())
    for sub in list(found):
        found |= _all_subclasses(sub)
    return found


def test_the_documented_exception_tree_is_the_real_one() -> None:
    for package in PACKAGES:
        root = importlib.import_module(package)
        for info in pkgutil.walk_packages(root.__path__, f"{package}."):
            if not info.name.endswith("__main__"):
                importlib.import_module(info.name)
    documented = set(re.findall(r"[├└]── (\w+)\s+\(([\w.]+)\)", inspect.getdoc(errors) or ""))
    real = {
        (cls.__name__, cls.__module__) for cls in _all_subclasses(HrcError) if cls.__module__.split(".")[0] in PACKAGES
    }
    assert documented == real
