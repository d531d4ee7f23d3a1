"""One chart per measure of a study report: the conditions' distributions (box plots) under each participant's
line across the conditions (matplotlib's object API on the Agg canvas: no pyplot state)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .report import Row, StudyReport

DPI = 120


def plot_file_name(measure: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", measure) + ".png"


def plot_measures(report: StudyReport, rows: Sequence[Row], out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for measure in report.measures:
        conditions = list(measure.conditions)
        values = {(r.participant, r.condition): r.value for r in rows
                  if r.measure == measure.measure and r.value is not None}
        fig = Figure(figsize=(1.6 + 1.4 * len(conditions), 4.2), layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        data = [[v for (p, c), v in values.items() if c == cond] for cond in conditions]
        ax.boxplot(data, positions=range(1, len(conditions) + 1), widths=0.5, showfliers=False,
                   medianprops={"color": "#e07b00"})
        for participant in sorted({p for p, _ in values}):
            xs = [i + 1 for i, c in enumerate(conditions) if (participant, c) in values]
            ys = [values[(participant, conditions[x - 1])] for x in xs]
            ax.plot(xs, ys, marker="o", markersize=3, linewidth=0.8, alpha=0.6, color="#1f5fa8")
        ax.set_xticks(range(1, len(conditions) + 1), [f"{c}\n(n={len(d)})" for c, d in zip(conditions, data)])
        missing = sum(measure.missing.values())
        ax.set_title(measure.measure + (f"  ({missing} missing)" if missing else ""), fontsize=10)
        ax.set_ylabel(measure.measure)
        ax.grid(axis="y", alpha=0.3)
        path = out_dir / plot_file_name(measure.measure)
        fig.savefig(path, dpi=DPI)
        written.append(path)
    return written
