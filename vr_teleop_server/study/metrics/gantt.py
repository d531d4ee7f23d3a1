"""Gantt chart of a trial in the style of Hoffman's fluency papers: one row per agent, actions as bars.

Uses matplotlib's object API with the Agg canvas (no pyplot, no global figure state), so it runs headless.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from . import intervals
from .fluency import ClippedAction, clip_actions, compute_metrics
from .model import FluencyResult, StateUpdate

_ROWS = (("robot", 1.0, "#4C72B0"), ("human", 0.0, "#DD8452"))
_ROW_HEIGHT = 0.72


def _lanes(actions: Sequence[ClippedAction]) -> tuple[list[int], int]:
    """Stack overlapping actions of one agent in lanes (first lane free at the start), so none hides another."""
    ends: list[float] = []
    lanes = [0] * len(actions)
    for i in sorted(range(len(actions)), key=lambda k: (actions[k].start, actions[k].end)):
        a = actions[i]
        lane = next((j for j, end in enumerate(ends) if end <= a.start), len(ends))
        if lane == len(ends):
            ends.append(a.end)
        else:
            ends[lane] = a.end
        lanes[i] = lane
    return lanes, max(1, len(ends))


def _complement(spans: list[tuple[float, float]], t0: float, t1: float) -> list[tuple[float, float]]:
    out, cursor = [], t0
    for a, b in intervals.union(spans):
        if a > cursor:
            out.append((cursor, a))
        cursor = max(cursor, b)
    if cursor < t1:
        out.append((cursor, t1))
    return out


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def plot_gantt(
    updates: Iterable[StateUpdate],
    path: Path | str,
    *,
    result: FluencyResult | None = None,
    shade: bool = True,
    title: str | None = None,
    dpi: int = 120,
) -> Path:
    """Draw the trial to a PNG at `path` (window, clipping and unfinished marks as in `result`)."""
    ups = list(updates)
    if result is None:
        result = compute_metrics(ups)
    t0, t1 = result.t0, result.t1
    actions = clip_actions(ups, t0, t1)
    span = max(t1 - t0, 1e-9)

    fig = Figure(figsize=(13, 4.2), dpi=dpi, layout="constrained")
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    renderer = canvas.get_renderer()

    spans = {agent: [(a.start, a.end) for a in actions if a.agent == agent] for agent, _, _ in _ROWS}
    if shade:
        for agent, y, _ in _ROWS:
            idle = [(a, b - a) for a, b in _complement(spans[agent], t0, t1)]
            ax.broken_barh(idle, (y - _ROW_HEIGHT / 2, _ROW_HEIGHT), facecolors="#d9d9d9", edgecolor="none",
                           zorder=0)
        both = intervals.intersection(spans["human"], spans["robot"])
        ax.broken_barh([(a, b - a) for a, b in both], (-0.5, 2.0), facecolors="#55A868", alpha=0.18,
                       edgecolor="none", zorder=0)

    labels = []
    for agent, y, colour in _ROWS:
        mine = [a for a in actions if a.agent == agent]
        lanes, n_lanes = _lanes(mine)
        lane_h = _ROW_HEIGHT / n_lanes
        for action, lane in zip(mine, lanes):
            bottom = y + _ROW_HEIGHT / 2 - (lane + 1) * lane_h
            width = action.end - action.start
            if width == 0:  # zero-length: a tick, so the event is still visible
                ax.vlines(action.start, bottom, bottom + lane_h, colors=colour, linewidth=2, zorder=3)
            else:
                ax.broken_barh([(action.start, width)], (bottom + 0.02 * lane_h, 0.96 * lane_h),
                               facecolors=colour, edgecolor="black", linewidth=0.6,
                               hatch="///" if action.unfinished else None, zorder=2)
            name = action.action + (" (unfinished)" if action.unfinished else "")
            if width == 0:  # label beside the tick, written upwards
                text = ax.annotate(name, (action.start, bottom + lane_h / 2), xytext=(2, 0),
                                   textcoords="offset points", rotation=90, ha="left", va="center",
                                   fontsize=7, annotation_clip=True, zorder=4)
            else:
                text = ax.text(action.start + width / 2, bottom + lane_h / 2, name, ha="center", va="center",
                               fontsize=8, clip_on=True, zorder=4,
                               bbox=dict(facecolor="white", alpha=0.75, edgecolor="none", pad=1)
                               if action.unfinished else None)
            labels.append((text, width, lane_h))

    for t, name in ((t0, "T0"), (t1, "T1")):
        ax.axvline(t, color="black", linestyle="--", linewidth=1, zorder=5)
        ax.annotate(name, (t, 1.0), xycoords=("data", "axes fraction"), xytext=(0, 3),
                    textcoords="offset points", ha="center", va="bottom", fontsize=9)

    pad = 0.02 * span
    ax.set_xlim(t0 - pad, t1 + pad)
    ax.set_ylim(-0.5, 1.5)
    ax.set_yticks([y for _, y, _ in _ROWS], [agent.capitalize() for agent, _, _ in _ROWS])
    ax.set_xlabel("time (s)")
    ax.grid(axis="x", color="#eeeeee", zorder=-1)
    ax.set_axisbelow(True)
    headline = (f"H-IDLE {_fmt(result.h_idle)}   R-IDLE {_fmt(result.r_idle)}   C-ACT {_fmt(result.c_act)}   "
                f"F-DEL {_fmt(result.f_del)}   T = {result.efficiency_s:.2f} s")
    ax.set_title(f"{title}\n{headline}" if title else headline, fontsize=10, pad=14)
    handles = [Patch(facecolor=c, edgecolor="black", label=f"{a} action") for a, _, c in _ROWS]
    if any(a.unfinished for a in actions):
        handles.append(Patch(facecolor="white", edgecolor="black", hatch="///", label="unfinished at T1"))
    if shade:
        handles += [Patch(facecolor="#d9d9d9", label="idle"), Patch(facecolor="#55A868", alpha=0.3, label="concurrent")]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8, frameon=False)

    # Labels go horizontally when they fit the bar, else vertically, else they are shortened.
    canvas.draw()
    x_px = ax.transData.transform([(0, 0), (1, 0)])
    px_per_s = x_px[1][0] - x_px[0][0]
    px_per_y = abs(ax.transData.transform([(0, 1)])[0][1] - ax.transData.transform([(0, 0)])[0][1])
    for text, width, lane_h in labels:
        bar_w, bar_h = width * px_per_s, lane_h * px_per_y
        box = text.get_window_extent(renderer)
        if width > 0 and box.width <= bar_w - 4 and box.height <= bar_h:
            continue
        text.set_rotation(90)
        text.set_fontsize(7)
        full = text.get_text()
        while True:
            box = text.get_window_extent(renderer)
            if box.height <= bar_h - 4 and (width == 0 or box.width <= max(bar_w, 12)):
                break
            if len(text.get_text()) <= 2:
                text.set_visible(False)
                break
            full = full[:-1]
            text.set_text(full.rstrip() + "…")
    path = Path(path)
    fig.savefig(path, format="png")
    return path
