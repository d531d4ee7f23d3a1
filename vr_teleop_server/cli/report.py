"""Reports for a person: a short table of the figures that matter, with units, and what a figure means where it
could be misread (a zero on a simulated clock). The full reports are JSON files for programs (`--json`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table


def _console() -> Console:
    # no colours or markup in a pipe or a file; a wide table in a narrow terminal folds rather than cuts
    console = Console(highlight=False, soft_wrap=False)
    if not console.is_terminal:
        console.width = 120
    return console


def _n(x: float | None, unit: str = "", digits: int = 1) -> str:
    return "n/a" if x is None else f"{x:.{digits}f}{unit}"


def replay_summary(result: dict[str, Any], plot: Path | None = None, console: Console | None = None) -> None:
    """A replay's report (tools/replay.py report()) as a two-column table."""
    console = console or _console()
    simulated = result["clock"] == "simulated"
    table = Table(title=f"replay of {result['file']}", title_justify="left", show_header=False, box=None,
                  pad_edge=False)
    table.add_column(style="bold", no_wrap=True)
    table.add_column(overflow="fold")
    speed = f"x{result['speed_achieved']}" if result["speed_achieved"] else "n/a"
    clock = "simulated clock (in-process server on the stand-in)" if simulated else f"server {result['server']}"
    table.add_row("session", f"{result['session_s']} s, replayed in {result['replay_s']} s ({speed}) on a {clock}")
    table.add_row("sent", f"{result['messages_sent']} messages, {result['calls_sent']} calls "
                          f"({result['calls_answered']} answered)")
    lat = result["latency_ms"]
    if lat["n"] == 0:
        latency = "no head command answered a pose (was control taken?)"
    elif simulated and not lat["max"]:
        latency = f"0 ms over {lat['n']} poses: simulated clock, no network (the server's time is not counted)"
    else:
        latency = (f"median {_n(lat['p50'], ' ms')}, 99% under {_n(lat['p99'], ' ms')}, "
                   f"max {_n(lat['max'], ' ms')} ({lat['n']} poses)")
    table.add_row("pose to command", latency)
    err = result["tracking_error_deg"]
    if err["n"] == 0:
        tracking = "no commands to compare"
    elif simulated and not err["max"]:
        tracking = (f"0° over {err['n']} commands: the server computed exactly what the offline mapping does "
                    "(on a simulated clock no timing differs)")
    else:
        tracking = (f"mean {_n(err['mean'], '°', 2)}, 99% under {_n(err['p99'], '°', 2)}, "
                    f"max {_n(err['max'], '°', 2)} ({err['n']} commands, against the offline mapping)")
    table.add_row("tracking error", tracking)
    received, expected = result["commands_received"], result["commands_expected"]
    parts = sorted(set(received) | set(expected))
    table.add_row("joint commands", ", ".join(f"{p} {received.get(p, 0)}/{expected.get(p, 0)}" for p in parts)
                  + " (received/expected)" if parts else "none")
    cam = result["camera"]
    age = "age 0 ms: simulated clock, rendered when due" if simulated and not cam["age_ms_p99"] else \
        f"age median {_n(cam['age_ms_p50'], ' ms')}, 99% under {_n(cam['age_ms_p99'], ' ms')}"
    table.add_row("camera", f"{cam['frames']} frames, {cam['fps']} fps, {age}" if cam["frames"]
                  else "not subscribed (--no-camera), or no frames")
    menu = result["menu"]
    if menu["selected"]:
        failed = "; ".join(f"{k}: {v}" for k, v in list(menu["failed"].items())[:3])
        table.add_row("menu", f"{menu['acknowledged']} of {menu['selected']} selections acknowledged"
                      + (f"; failed: {failed}" if failed else "")
                      + f" ({len(menu['not_selected'])} of the server's {menu['items_on_server']} items never tried)")
    errors = result["errors"]
    first = (errors["status"] + [f"{k}: {v}" for k, v in errors["failed_calls"].items()])[:3]
    table.add_row("errors", "none" if not errors["count"] else f"{errors['count']}: " + "; ".join(map(str, first)))
    autonomy = result.get("autonomy") or {}
    if autonomy:
        attention = autonomy.get("attention") or {}
        table.add_row("recorded session", f"{autonomy.get('proposals', 0)} robot proposals, "
                      f"{autonomy.get('teacher_initiated', 0)} teacher actions, {attention.get('speeches', 0)} "
                      "pupils' speeches (read from the file, not replayed; all measures: --json)")
    if plot is not None:
        table.add_row("plot", str(plot))
    console.print(table)
