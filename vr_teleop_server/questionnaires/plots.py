"""Charts for the questionnaire reports, drawn with matplotlib's object API on the Agg canvas.

Nothing here touches pyplot, so no global figure state or GUI backend is involved; the file type follows the
output name's suffix (PNG by default).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .godspeed import GodspeedReport
from .qam import QAMDefinition, QAMReport, QAMSubsetResult
from .stats import Describe
from .sus import SUSReport
from .tlx import TLXReport

EXPECTED_COLOR = "#1f5fa8"
PERCEIVED_COLOR = "#e07b00"
BAND_COLORS = ("#eef3f9", "#f8f1e7")
DPI = 150


def _save(fig: Figure, out: str | Path) -> Path:
    out = Path(out)
    FigureCanvasAgg(fig)
    fig.savefig(out, dpi=DPI)
    return out


def _iqr_errors(stats: Sequence[Describe]) -> np.ndarray:
    lower = [0.0 if d.median is None else d.median - d.q1 for d in stats]
    upper = [0.0 if d.median is None else d.q3 - d.median for d in stats]
    return np.array([lower, upper])


def _medians(stats: Sequence[Describe]) -> np.ndarray:
    return np.array([np.nan if d.median is None else d.median for d in stats])


def plot_qam(report: QAMReport, definition: QAMDefinition, out: str | Path) -> Path:
    """Expected against perceived per parameter (the paper's Fig. 9): one panel per condition/role subset,
    parameters grouped and labelled by actor, medians with IQR bars when there are several raters."""
    group_gap = 1.0
    x_of: dict[int, float] = {}
    spans = []  # (group, first x, last x)
    offset = 0.0
    for g_index, group in enumerate(definition.groups):
        params = definition.in_group(group.id)
        xs = [offset + i for i in range(len(params))]
        x_of.update({p.id: x for p, x in zip(params, xs)})
        spans.append((group, xs[0], xs[-1]))
        offset = xs[-1] + 1 + group_gap
    n_panels = len(report.subsets)
    fig = Figure(figsize=(16, 3.2 + 3.6 * n_panels), layout="constrained")
    axes = fig.subplots(n_panels, 1, sharex=True, squeeze=False)[:, 0]
    likert = definition.likert
    for ax, subset in zip(axes, report.subsets):
        _qam_panel(ax, subset, definition, x_of, spans, report.by)
        ax.set_ylim(likert.min - 0.6, likert.max + 0.75)
        ax.set_yticks(range(likert.min, likert.max + 1))
        ax.set_yticklabels([f"{k}  {likert.labels[k].replace(' influential', '')}"
                            for k in range(likert.min, likert.max + 1)], fontsize=9)
        ax.set_xlim(-0.7, offset - group_gap - 0.3)
        ax.grid(axis="y", color="#d0d0d0", linewidth=0.6)
        ax.set_axisbelow(True)
    params = definition.parameters
    axes[-1].set_xticks([x_of[p.id] for p in params])
    axes[-1].set_xticklabels([f"{p.short}  {p.id}" for p in params], rotation=55, ha="right",
                             rotation_mode="anchor", fontsize=8.5)
    axes[-1].set_xlabel("QAM parameter (number as in the paper's Table 1)", fontsize=10)
    several = any(max(p.expected.n, p.perceived.n) > 1 for s in report.subsets for p in s.parameters)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper right", ncols=len(labels), fontsize=10, frameon=False)
    what = "medians, bars: IQR" if several else "one rater"
    fig.suptitle(f"QAM: expected vs perceived influence per parameter ({what})", x=0.01, ha="left",
                 fontsize=13, fontweight="bold")
    return _save(fig, out)


def _short(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


def _qam_panel(ax, subset: QAMSubsetResult, definition: QAMDefinition, x_of: dict[int, float], spans,
               by: str | None) -> None:
    shift = 0.14
    diff_row = definition.likert.max + 0.45  # a strip above the scale for the median differences
    ax.text(-0.02, diff_row, "diff", transform=ax.get_yaxis_transform(), ha="right", va="center", fontsize=9,
            color="#333333")
    for index, (group, first, last) in enumerate(spans):
        ax.axvspan(first - 0.5, last + 0.5, color=BAND_COLORS[index % 2], zorder=0, linewidth=0)
        label = group.long_name or group.name
        ax.text((first + last) / 2, 1.0, label, transform=ax.get_xaxis_transform(), ha="center", va="bottom",
                fontsize=10.5, fontweight="bold")
    by_id = {p.id: p for p in subset.parameters}
    for group, first, last in spans:
        params = [by_id[p.id] for p in definition.in_group(group.id)]
        xs = np.array([x_of[p.id] for p in params])
        for phase, sign, color, marker, style in (("expected", -1, EXPECTED_COLOR, "o", "--"),
                                                  ("perceived", 1, PERCEIVED_COLOR, "s", "-")):
            stats = [getattr(p, phase) if not p.objective else Describe(n=0, missing=0) for p in params]
            ys = _medians(stats)
            label = f"{phase} ({'before' if phase == 'expected' else 'after'} the trial)" if group is spans[0][0] \
                else None
            ax.plot(xs + sign * shift, ys, linestyle=style, color=color, linewidth=1.0, marker=marker,
                    markersize=7.5, label=label, zorder=3)
            if any(d.n > 1 for d in stats):
                ax.errorbar(xs + sign * shift, ys, yerr=_iqr_errors(stats), fmt="none", ecolor=color,
                            elinewidth=1.1, capsize=3, zorder=2)
        for p in params:
            x = x_of[p.id]
            if p.objective:
                ax.axvspan(x - 0.42, x + 0.42, facecolor="white", edgecolor="#9a9a9a", hatch="///",
                           linewidth=0.5, zorder=1)
                medians = (p.expected.median, p.perceived.median)
                text = "objective: own scale" if medians == (None, None) else \
                    f"objective: E {_short(medians[0])}, P {_short(medians[1])}"
                ax.text(x, 3, text, rotation=90, ha="center", va="center", fontsize=7.5,
                        color="#555555", zorder=4,
                        bbox=dict(facecolor="white", edgecolor="none", pad=1.0))
            elif p.difference:
                color = "#1a7f37" if p.difference > 0 else "#b3261e"
                ax.text(x, diff_row, f"{p.difference:+g}", ha="center", va="center", fontsize=9,
                        fontweight="bold", color=color, zorder=4)
    title = "all respondents" if by is None else f"{by}: {subset.label}"
    ax.set_title(f"{title}  (expected rows: {subset.expected_rows}, perceived rows: {subset.perceived_rows}, "
                 f"raters in both: {subset.paired_raters})", loc="left", fontsize=9.5, pad=18, color="#333333")


def plot_sus(report: SUSReport, out: str | Path) -> Path:
    """SUS scores per group: box plot with every respondent's score, and the mean."""
    labels = [s.label for s in report.subsets]
    data = [[r.score for r in _members(report.respondents, report.by, s.label) if r.score is not None]
            for s in report.subsets]
    fig = Figure(figsize=(max(5.5, 1.6 * len(labels) + 3), 5.5), layout="constrained")
    ax = fig.subplots()
    _box_with_points(ax, data, labels)
    ax.axhline(68, color="#888888", linestyle=":", linewidth=1)
    ax.text(0.99, 68, "68: average SUS across published studies (Sauro 2011)", transform=ax.get_yaxis_transform(),
            ha="right", va="bottom", fontsize=8, color="#555555")
    ax.set_ylim(-3, 103)
    ax.set_ylabel("SUS score (0-100)")
    ax.set_title("System Usability Scale", loc="left", fontweight="bold")
    return _save(fig, out)


def plot_tlx(report: TLXReport, out: str | Path) -> Path:
    """Mean rating per subscale, raw and weighted TLX, per group, with SD bars."""
    keys = list(report.subscale_labels)
    weighted_n = "/".join(str(s.weighted.n) for s in report.subsets)
    names = [report.subscale_labels[k] for k in keys] + ["Raw TLX", f"Weighted TLX\n(n={weighted_n} with weights)"]
    fig = Figure(figsize=(11, 5.5), layout="constrained")
    ax = fig.subplots()
    width = 0.8 / max(1, len(report.subsets))
    x = np.arange(len(names), dtype=float)
    x[-2:] += 0.5  # set the overall scores apart from the subscales
    for index, subset in enumerate(report.subsets):
        stats = [subset.subscales[k] for k in keys] + [subset.raw, subset.weighted]
        means = np.array([np.nan if d.mean is None else d.mean for d in stats])
        sds = np.array([0.0 if d.sd is None else d.sd for d in stats])
        pos = x - 0.4 + width * (index + 0.5)
        ax.bar(pos, np.nan_to_num(means), width * 0.92, yerr=sds, capsize=3, label=f"{subset.label} "
               f"(n={subset.raw.n})", color=f"C{index}", alpha=0.85)
    ax.axvline((x[-3] + x[-2]) / 2, color="#999999", linewidth=0.8)
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=20, ha="right")
    ax.set_ylim(0, 105)
    ax.set_ylabel("rating (0-100, mean with SD)")
    ax.set_title("NASA-TLX workload", loc="left", fontweight="bold")
    ax.legend(fontsize=9, frameon=False, loc="upper left")
    ax.grid(axis="y", color="#dddddd", linewidth=0.6)
    ax.set_axisbelow(True)
    return _save(fig, out)


def plot_godspeed(report: GodspeedReport, out: str | Path) -> Path:
    """Series means per group (bars, SD) with each respondent's series score as a dot."""
    names = [s.name for s in report.subsets[0].series]
    ids = [s.id for s in report.subsets[0].series]
    fig = Figure(figsize=(10, 5.5), layout="constrained")
    ax = fig.subplots()
    width = 0.8 / max(1, len(report.subsets))
    x = np.arange(len(names), dtype=float)
    rng = np.random.default_rng(0)  # fixed jitter, so the same sheet gives the same picture
    for index, subset in enumerate(report.subsets):
        pos = x - 0.4 + width * (index + 0.5)
        means = np.array([np.nan if s.score.mean is None else s.score.mean for s in subset.series])
        sds = np.array([0.0 if s.score.sd is None else s.score.sd for s in subset.series])
        bottom = 1.0  # bars start at the scale's minimum
        ax.bar(pos, np.nan_to_num(means - bottom), width * 0.92, bottom=bottom, yerr=sds, capsize=3,
               color=f"C{index}", alpha=0.75, label=f"{subset.label} (n={subset.rows})")
        members = _members(report.respondents, report.by, subset.label)
        for px, sid in zip(pos, ids):
            ys = [m.series[sid] for m in members if m.series[sid] is not None]
            ax.scatter(px + rng.uniform(-width * 0.25, width * 0.25, len(ys)), ys, s=12, color="black",
                       alpha=0.6, zorder=3, linewidths=0)
    ax.set_xticks(x)
    ax.set_xticklabels(names)
    ax.set_ylim(0.85, 5.2)
    ax.set_yticks([1, 2, 3, 4, 5])
    ax.set_ylabel("series mean (1-5; bars: mean with SD)")
    ax.set_title("Godspeed questionnaire series", loc="left", fontweight="bold")
    ax.legend(fontsize=9, frameon=False, loc="upper right")
    ax.grid(axis="y", color="#dddddd", linewidth=0.6)
    ax.set_axisbelow(True)
    return _save(fig, out)


def _members(respondents, by: str | None, label: str):
    if by is None:
        return list(respondents)
    return [r for r in respondents if (getattr(r, by) or f"(no {by})") == label]


def _box_with_points(ax, data: list[list[float]], labels: list[str]) -> None:
    rng = np.random.default_rng(0)
    positions = np.arange(1, len(data) + 1)
    filled = [d if d else [np.nan] for d in data]
    ax.boxplot(filled, positions=positions, widths=0.5, showfliers=False, medianprops=dict(color="black"))
    for pos, values in zip(positions, data):
        ax.scatter(pos + rng.uniform(-0.12, 0.12, len(values)), values, s=16, color="C0", alpha=0.7, zorder=3,
                   linewidths=0)
        if values:
            ax.scatter([pos], [np.mean(values)], marker="D", color="C3", s=40, zorder=4,
                       label="mean" if pos == 1 else None)
    ax.set_xticks(positions)
    ax.set_xticklabels([f"{label}\n(n={len(values)})" for label, values in zip(labels, data)])
    if any(data):
        ax.legend(fontsize=9, frameon=False, loc="lower left")
