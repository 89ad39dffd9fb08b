"""What bounds δ under ``lucci2020_pfl``, with each effective-mass model, on the collaborative suite.

For every decision of every robot, :meth:`gateway.methods.ContactAware.bounded_by` names what bounded δ
(``none``, ``separation:<region>``, ``clamping:<region>``, ``contact:<region>``). This benchmark runs the same cases
with ``pfl_mass_model = "link_bound"`` (the default) and ``"simple"`` (M/2 + m_payload, test-only, so it sets
``HRC_ALLOW_UNSAFE=pfl_simple_mass_for_tests`` for itself) and prints, per model, the program cycles of each case and
how often each label bounded δ. The mass model can only change δ where a ``contact:`` label binds.

    .venv/bin/python -m bench.pfl_bounded_by --scenarios 8 --duration-s 30 --seed 0
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager

from bench.productivity import run_variant
from gateway.methods import ContactAware
from hrc_contract.config import CellConfig
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.config import load_cell_config

MASS_MODELS = ("link_bound", "simple")


@contextmanager
def tallied(counts: Counter[str]) -> Iterator[None]:
    """While inside, every :meth:`ContactAware.bound` adds its :meth:`ContactAware.bounded_by` label to ``counts``."""
    original = ContactAware.bound

    def bound(self: ContactAware, x: object) -> float:
        delta = original(self, x)  # type: ignore[arg-type]
        counts[self.bounded_by(x.robot.name) or "none"] += 1  # type: ignore[attr-defined]
        return delta

    ContactAware.bound = bound  # type: ignore[method-assign]
    try:
        yield
    finally:
        ContactAware.bound = original  # type: ignore[method-assign]


@contextmanager
def simple_mass_allowed() -> Iterator[None]:
    """``HRC_ALLOW_UNSAFE`` names the simple mass while inside (the comparison needs it), as it was afterwards."""
    before = os.environ.get("HRC_ALLOW_UNSAFE")
    os.environ["HRC_ALLOW_UNSAFE"] = "pfl_simple_mass_for_tests"
    try:
        yield
    finally:
        if before is None:
            del os.environ["HRC_ALLOW_UNSAFE"]
        else:
            os.environ["HRC_ALLOW_UNSAFE"] = before


def with_mass_model(config: CellConfig, model: str) -> CellConfig:
    """``config`` with ``safety.pfl_mass_model`` set (validated)."""
    raw = config.model_dump()
    raw["safety"]["pfl_mass_model"] = model
    return CellConfig.model_validate(raw)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.pfl_bounded_by", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", type=int, default=8, help="cases of the collaborative suite (default 8)")
    parser.add_argument("--duration-s", type=float, default=30.0, help="simulated time per case [s] (default 30)")
    parser.add_argument("--seed", type=int, default=0, help="suite seed (default 0)")
    parser.add_argument("--config", default=None, help="cell configuration (default configs/cell.toml)")
    args = parser.parse_args(argv)
    if args.scenarios < 1 or not args.duration_s > 0.0:
        parser.error("--scenarios must be at least 1 and --duration-s above 0")
    base = load_cell_config(args.config)
    robots = {name: load_robot_model(name, robot) for name, robot in base.robots.items()}
    labels: dict[str, Counter[str]] = {}
    with simple_mass_allowed():  # run_variant validates the config again
        for model in MASS_MODELS:
            config = with_mass_model(base, model)
            labels[model] = Counter()
            with tallied(labels[model]):
                for index in range(args.scenarios):
                    run = run_variant(
                        config, robots, args.seed, index, args.duration_s, "lucci2020_pfl", suite="collaborative"
                    )
                    print(
                        f"{model:10s} case {index} {run.kind:14s} cycles {run.program_cycles:.3f} "
                        f"mean δ {run.mean_delta:.4f}",
                        flush=True,
                    )
    print("\nwhat bounded δ (decisions):")
    names = sorted(set().union(*labels.values()), key=lambda n: -labels[MASS_MODELS[0]][n])
    print(f"{'label':22s}" + "".join(f"{m:>12s}" for m in MASS_MODELS))
    for name in names:
        print(f"{name:22s}" + "".join(f"{labels[m][name]:12d}" for m in MASS_MODELS))
    for model in MASS_MODELS:
        total = sum(labels[model].values())
        contact = sum(n for label, n in labels[model].items() if label.startswith("contact:"))
        print(
            f"{model}: contact rows bound δ in {contact} of {total} decisions ({100 * contact / max(total, 1):.2f} %)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
