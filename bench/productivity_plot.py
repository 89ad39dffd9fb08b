"""The productivity benchmark's plot: program cycles per hour per method and kind of case, one panel per suite.

Each panel is one result document of :mod:`bench.productivity` (a suite): per group of cases (all cases within the
delay budget, then each kind), one bar per override method, and the two bounds of the group marked across it: the
robot alone (``no_human``, solid) and eq. (15) with zero delay (dashed). A bar whose variant had violations is
hatched and starred: its figure does not count. Drawn with matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hrc_contract.errors import HrcError

METHOD_COLORS = {
    "zanchettin2016": "#1f77b4",
    "zanchettin2016_speed_aware": "#2ca02c",
    "iso15066": "#9467bd",
    "three_zones": "#ff7f0e",
    "stop_only": "#d62728",
}
"""The methods drawn as bars, in order, with their colours."""
NO_HUMAN = "no_human"
ZERO_DELAY = "zanchettin2016_zero_delay"
GROUP_WIDTH = 0.8
"""Width of one group of bars on the x axis (groups are 1 apart)."""


class PlotError(HrcError):
    """The plot cannot be drawn (matplotlib missing, or a document without figures)."""


def panel_groups(doc: dict[str, Any]) -> list[tuple[str, dict[str, dict[str, Any]]]]:
    """The groups of one result document: ("all", figures within budget), then (kind, figures) per kind."""
    results = doc.get("results", {})
    if "within_budget" not in results:
        raise PlotError("not a productivity result: no results.within_budget (run python -m bench.productivity)")
    within = results["within_budget"]
    groups = [(f"all ({within['cases']})", within["figures"])]
    for kind, part in results.get("within_budget_by_kind", {}).items():
        groups.append((f"{kind} ({part['cases']})", part["figures"]))
    return groups


def _draw_panel(ax: Any, doc: dict[str, Any]) -> None:
    groups = panel_groups(doc)
    bar_width = GROUP_WIDTH / len(METHOD_COLORS)
    for g, (_, figures) in enumerate(groups):
        for m, (method, color) in enumerate(METHOD_COLORS.items()):
            f = figures.get(method)
            if f is None or f["cycles_per_hour"] is None:
                continue
            x = g - GROUP_WIDTH / 2 + (m + 0.5) * bar_width
            counts = bool(f["counts"])
            label = method if g == 0 else None
            ax.bar(x, f["cycles_per_hour"], bar_width, color=color, hatch=None if counts else "//", label=label)
            if not counts:
                ax.text(x, f["cycles_per_hour"], "*", ha="center", va="bottom")
        left, right = g - GROUP_WIDTH / 2, g + GROUP_WIDTH / 2
        for variant, style, name in (
            (NO_HUMAN, "-", "robot alone (no human)"),
            (ZERO_DELAY, "--", "eq. (15), zero delay"),
        ):
            bound = figures.get(variant, {}).get("cycles_per_hour")
            if bound is not None:
                ax.hlines(bound, left, right, colors="black", linestyles=style, label=name if g == 0 else None)
    params = doc.get("parameters", {})
    occlusion = ", occlusion" if params.get("occlusion") else ""
    ax.set_title(
        f"{params.get('suite', '?')} suite{occlusion}: {params.get('scenarios', '?')} cases × "
        f"{params.get('duration_s', '?')} s, seed {params.get('seed', '?')} (within the delay budget)"
    )
    ax.set_xticks(range(len(groups)), [name for name, _ in groups])
    ax.set_ylabel("program cycles / h")
    ax.set_ylim(bottom=0.0)
    ax.grid(axis="y", alpha=0.3)


def plot_cycles_per_hour(docs: Sequence[dict[str, Any]], path: Path) -> Path:
    """Draw one panel per result document (suite) into a PNG at ``path`` (folders created); returns ``path``.

    Raises:
        PlotError: matplotlib is not installed, or a document has no productivity figures.
    """
    if not docs:
        raise PlotError("nothing to plot: no result documents")
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise PlotError(
            f"matplotlib is needed for the plot ({exc}); install the dev extra: scripts/bootstrap.sh"
        ) from None
    figure = Figure(figsize=(11.0, 4.2 * len(docs)), layout="constrained")
    FigureCanvasAgg(figure)  # the Agg canvas: no display, PNG output
    axes = figure.subplots(len(docs), 1, squeeze=False)[:, 0]
    for ax, doc in zip(axes, docs, strict=True):
        _draw_panel(ax, doc)
    handles, labels = axes[0].get_legend_handles_labels()
    if handles:  # none when no group has a figure (e.g. every case beyond the delay budget)
        axes[0].legend(handles, labels, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize="small")
    figure.supxlabel("hatched, *: the variant had violations (its figure does not count)", fontsize="small")
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, format="png", dpi=100)
    return path
