"""`vr-teleop replay FILE... --speed max [--workers K | --scheduler ADDR] [--summary OUT]`: many recordings
replayed as `replay FILE --speed max` replays one (a server of its own on the stand-in, a simulated clock), one
after another or on Dask workers (tools/distributed.py), and one summary table of them: OUT.csv and OUT.json, one
row per session.

The recordings are read here and their operator's messages sent to the workers, so the workers need neither the
files nor a shared directory.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .distributed import Workers, WorkersError, run_all
from ..recording.format import check_recording
from .replay import Step, load_steps, report, run_simulated


@dataclass(frozen=True, eq=False)  # a job is itself (the steps' payloads do not hash)
class ReplayJob:
    index: int
    file: str
    client: str
    steps: tuple[Step, ...]
    camera: bool = True

    @property
    def key(self) -> str:
        return f"replay-{self.index}-{Path(self.file).stem}"


def load_jobs(files: list[Path], client: str | None = None, camera: bool = True) -> list[ReplayJob]:
    """Raises OSError or ValueError naming the file that is not a recording the replay can play."""
    jobs = []
    for index, path in enumerate(files):
        steps, who = load_steps(path, client)
        jobs.append(ReplayJob(index, str(path), who, tuple(steps), camera))
    return jobs


def replay_job(job: ReplayJob) -> dict[str, Any]:
    """One session, as `vr-teleop replay FILE --speed max` reports it (without --server)."""
    steps = list(job.steps)
    got, elapsed = run_simulated(steps, camera=job.camera, progress=False)
    return {"file": job.file, "client": job.client, "server": "in-process (stand-in, simulated clock)",
            **report(steps, got, elapsed, math.inf)}


def replay_all(jobs: list[ReplayJob], workers: Workers, progress: bool = True) -> list[dict[str, Any]]:
    """The reports in the order of the files."""
    done = dict(run_all(replay_job, jobs, workers, name=lambda job: job.key, progress=progress, unit="session"))
    return [done[job] for job in jobs]


def row(result: dict[str, Any]) -> dict[str, Any]:
    """One report as one flat row: nested keys joined with '.', lists as JSON."""
    out: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for key, inner in value.items():
                walk(f"{prefix}.{key}" if prefix else str(key), inner)
        else:
            out[prefix] = json.dumps(value) if isinstance(value, list) else value

    walk("", result)
    return out


def write_summary(results: list[dict[str, Any]], out: Path) -> tuple[Path, Path]:
    """OUT.csv and OUT.json (OUT without its extension), one row per session; columns in first-seen order."""
    rows = [row(r) for r in results]
    columns = list(dict.fromkeys(key for r in rows for key in r))
    base = out.with_suffix("") if out.suffix in (".csv", ".json") else out
    csv_path, json_path = base.with_name(base.name + ".csv"), base.with_name(base.name + ".json")
    with csv_path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    json_path.write_text(json.dumps(rows, indent=2) + "\n")
    return csv_path, json_path


SHOWN = (("session_s", "session s", "{:>10}"), ("replay_s", "replay s", "{:>9}"), ("speed_achieved", "speed", "{:>7}"),
         ("latency_ms.p50", "lat p50", "{:>8}"), ("latency_ms.p99", "lat p99", "{:>8}"),
         ("tracking_error_deg.mean", "track deg", "{:>9}"), ("camera.frames", "frames", "{:>7}"),
         ("errors.count", "errors", "{:>7}"))


def text_table(results: list[dict[str, Any]]) -> str:
    rows = [row(r) for r in results]
    width = max(len("file"), *(len(str(r["file"])) for r in rows))
    head = f"{'file':<{width}} " + " ".join(fmt.format(title) for _key, title, fmt in SHOWN)
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = " ".join(fmt.format("n/a" if r.get(key) is None else r[key]) for key, _title, fmt in SHOWN)
        lines.append(f"{str(r['file']):<{width}} {cells}")
    return "\n".join(lines)


def run_batch(args: Any) -> int:
    """The batch form of `vr-teleop replay` (cli/replay.py's flags): at --speed max, without --server."""
    def fail(message: str, code: int) -> int:
        print(f"vr-teleop replay: error: {message}", file=sys.stderr)
        return code

    if not math.isinf(args.speed) or args.server is not None:
        return fail("a batch (several files, --workers, --scheduler or --summary) replays at --speed max without "
                    "--server, each session on a server of its own", 2)
    if args.json is not None or args.plot is not None:
        return fail("--json and --plot are for one recording; a batch writes --summary OUT (OUT.csv, OUT.json)", 2)
    try:
        cut_off = [path for path in args.file if not check_recording(path).closed]
        jobs = load_jobs(args.file, args.client, camera=not args.no_camera)
    except (OSError, ValueError) as exc:
        return fail(str(exc), 2)
    for path in cut_off:
        print(f"vr-teleop replay: {path}: cut off: the recording was not closed; replaying what is there",
              file=sys.stderr)
    try:
        results = replay_all(jobs, Workers.from_args(args), progress=not args.quiet)
    except WorkersError as exc:
        return fail(str(exc), 1)
    print(text_table(results))
    if args.summary is not None:
        for path in write_summary(results, args.summary):
            print(f"wrote {path}")
    if cut_off and not args.allow_truncated:
        print(f"vr-teleop replay: {len(cut_off)} recording{'s were' if len(cut_off) > 1 else ' was'} cut off: exit "
              "code 3 (--allow-truncated accepts them)", file=sys.stderr)
        return 3
    return 0
