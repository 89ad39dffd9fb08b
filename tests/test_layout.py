"""Rules that keep the layout (issue 18): the installed names listed here, no checkout paths from ``__file__``, curated
``__all__``, one definition per public function name in a package, the documented exception tree."""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import re
from collections import Counter
from pathlib import Path

import pytest
from setuptools import find_packages
from support.paths import REPO_ROOT

from hrc_contract import errors
from hrc_contract.errors import HrcError

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
