"""Many trials on Dask: the same batch (every trial of a study file x --repeat seeds, at --speed max) in this
process, on a local Dask cluster of 1 worker and of 2, as `vr-teleop study run --all --speed max --repeat N
--workers K` runs it. Prints:

- what one trial costs where it runs: wall and CPU seconds (with the stand-in's render process), peak memory;
- trials per minute with 1 and 2 workers, and their ratio (the issue's target: 2 workers on a 2-core machine at
  least 1.7x one), the clusters' start-up apart;
- the Dask layer's overhead per trial: a 1-worker batch's wall time less the trials' own wall times (measured
  inside the worker), per trial, against a trial's wall time (target: under 2%);
- whether the three tables are equal, metric for metric (they must be).

A classroom study (examples/classroom.yaml) is run first with `perception: rendered` and then `modelled` in this
process over the same seeds: each condition's attention measures (mean and 95% interval over the seeds) side by side,
whether the modelled mean falls in the rendered interval, and each lesson's cost per CPU second (the issue's
target: a supervised lesson at least x20 simulated per CPU second, modelled). The Dask batches then run with the
study's perception as --perception says (default modelled). Seeds: --repeat (3 by default for a classroom study).

Ratios only within one run: the machine may be shared. Say the load (`uptime`) beside the figures; the CPU-second
figures do not depend on it.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import statistics
import time
from pathlib import Path

from distributed import LocalCluster

from vr_teleop_server.study.kinds import kind_of, load_study
from vr_teleop_server.tools.distributed import Workers, run_all
from vr_teleop_server.study.classroom_file import ClassroomStudy
from vr_teleop_server.tools.study_runner import TrialDone, TrialJob, run_job

ROOT = Path(__file__).resolve().parent.parent


def batch(jobs: list[TrialJob], workers: Workers) -> tuple[dict[str, TrialDone], float]:
    started = time.perf_counter()
    done = {job.key: result for job, result in run_all(run_job, jobs, workers, name=lambda j: j.key, progress=False)}
    return done, time.perf_counter() - started


def on_cluster(jobs: list[TrialJob], count: int) -> tuple[dict[str, TrialDone], float, float]:
    """The batch on a local cluster of `count` workers started first: (results, batch wall, start-up wall)."""
    started = time.perf_counter()
    with LocalCluster(n_workers=count, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=logging.ERROR) as cluster:
        startup = time.perf_counter() - started
        done, wall = batch(jobs, Workers(scheduler=cluster.scheduler_address))
    return done, wall, startup


ATTENTION = ("onset_to_look_mean_s", "onset_to_look_p95_s", "share_attended", "effectiveness")


def sim_per_cpu(done: dict[str, TrialDone], jobs: list[TrialJob], trial: str) -> str:
    mine = [done[j.key] for j in jobs if j.trial == trial]
    return f"x{sum(d.report.live.duration_s for d in mine) / sum(d.cpu_s for d in mine):.1f}"


def _show(x: dict) -> str:
    if x["mean"] is None:
        return "n/a"
    return f"{x['mean']:.2f}" + ("" if x["ci95_low"] is None else f" [{x['ci95_low']:.2f}, {x['ci95_high']:.2f}]")


def compare_perception(study: ClassroomStudy, jobs: list[TrialJob],
                       names: list[str]) -> tuple[dict[str, TrialDone], float, bool]:
    """The lessons with rendered and with modelled perception in this process, same seeds: the attention measures
    side by side. Returns the modelled lessons and whether every modelled mean is in its rendered interval."""
    runs, walls = {}, {}
    for perception in ("rendered", "modelled"):
        arm = [dataclasses.replace(j, study=study.model_copy(update={"perception": perception})) for j in jobs]
        runs[perception], wall = batch(arm, Workers())
        walls[perception] = wall
        print(f"{perception}: {wall:.1f} s wall; simulated per CPU second (with the render process): "
              + ", ".join(f"{t} {sim_per_cpu(runs[perception], jobs, t)}" for t in names), flush=True)
    print(f"{'condition':<14} {'measure':<22} {'rendered mean [95% CI]':>30} {'modelled mean [95% CI]':>30}  in CI")
    inside, held, unheld = True, 0, 0
    for trial in names:
        s = {p: kind_of(study).summarise([runs[p][j.key].report for j in jobs if j.trial == trial]) for p in runs}
        for key in ATTENTION:
            r, m = s["rendered"][key], s["modelled"][key]
            if r["ci95_low"] is None or m["mean"] is None:  # fewer than 2 rendered values (a p95 is none when
                verdict = "no interval"  # a speech was never looked at): nothing to hold the modelled mean to
                unheld += 1
            else:
                ok = r["ci95_low"] - 1e-9 <= m["mean"] <= r["ci95_high"] + 1e-9
                inside &= ok
                held += 1
                verdict = "yes" if ok else "NO"
            print(f"{trial:<14} {key:<22} {_show(r):>30} {_show(m):>30}  {verdict}")
    print(f"modelled attention measures within the rendered runs' 95% intervals ({len(jobs) // len(names)} "
          f"seeds): {'all' if inside else 'NOT all'} of the {held} with an interval ({unheld} without)", flush=True)
    return runs["modelled"], walls["modelled"], inside


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("file", nargs="?", type=Path, default=ROOT / "examples" / "toolbox.yaml",
                        help="a study file: a task study (toolbox.yaml, the default) or a classroom one "
                             "(examples/classroom.yaml: its conditions are the trials)")
    parser.add_argument("--one-worker-only", action="store_true",
                        help="only this process's batch: per trial cost and speed (x simulated / wall), no cluster")
    parser.add_argument("--repeat", type=int, default=None,
                        help="seeds per trial (default 2; 3 for a classroom study, whose intervals need them)")
    parser.add_argument("--perception", choices=("rendered", "modelled"), default="modelled",
                        help="a classroom study's perception for the Dask batches (default modelled)")
    parser.add_argument("--no-compare", action="store_true",
                        help="a classroom study: skip the rendered-against-modelled lessons")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--trial", action="append", help="only these trials (default: all)")
    parser.add_argument("--lesson-s", type=float, default=None,
                        help="a classroom study's lesson cut to this many simulated seconds (a quicker measure)")
    args = parser.parse_args()
    study = load_study(args.file)
    if args.lesson_s is not None:
        study = study.model_copy(update={"lesson_s": args.lesson_s})
    classroom = isinstance(study, ClassroomStudy)
    args.repeat = args.repeat or (3 if classroom else 2)
    names = args.trial or list(study.trials)
    jobs = [TrialJob(study, name, seed, f"{name}-seed{seed}.mcap") for name in names
            for seed in range(args.seed, args.seed + args.repeat)]
    print(f"{len(jobs)} trials ({', '.join(names)} x seeds {args.seed}..{args.seed + args.repeat - 1}) of "
          f"{args.file.name} at --speed max; load {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)

    compared, inside = None, True
    if classroom and not args.no_compare:
        compared, compared_wall, inside = compare_perception(study, jobs, names)
    if classroom:
        study = study.model_copy(update={"perception": args.perception})
        jobs = [dataclasses.replace(j, study=study) for j in jobs]
        print(f"perception: {args.perception}", flush=True)
    if compared is not None and args.perception == "modelled":
        here, here_wall = compared, compared_wall
        print(f"in this process: the modelled lessons above, {here_wall:.1f} s", flush=True)
    else:
        here, here_wall = batch(jobs, Workers())
        print(f"in this process: {here_wall:.1f} s", flush=True)
    if args.one_worker_only:
        for job in jobs:
            d = here[job.key]
            sim = d.report.live.duration_s
            print(f"  {job.key}: {sim:.0f} s simulated in {d.wall_s:.1f} s wall (x{sim / d.wall_s:.2f}), "
                  f"CPU {d.cpu_s:.1f} s (x{sim / d.cpu_s:.2f} simulated per CPU second)")
        print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        return 0
    one, one_wall, one_start = on_cluster(jobs, 1)
    print(f"1 worker: {one_wall:.1f} s", flush=True)
    two, two_wall, two_start = on_cluster(jobs, 2)
    print(f"2 workers: {two_wall:.1f} s", flush=True)
    print(f"load after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")

    def per_trial(done: dict[str, TrialDone]) -> str:
        w = [d.wall_s for d in done.values()]
        c = [d.cpu_s for d in done.values()]
        sim = [d.report.live.duration_s for d in done.values()]
        return (f"wall {statistics.mean(w):5.2f} s (x{sum(sim) / sum(w):4.1f}), CPU {statistics.mean(c):5.2f} s, "
                f"peak RSS {max(d.peak_rss_mb for d in done.values()):4.0f} MB (with the render process)")

    print(f"per trial, in this process:   {per_trial(here)}")
    if classroom:
        print("simulated seconds per CPU second, this process (with the render process; target: supervised >= x20 "
              "modelled): " + ", ".join(f"{t} {sim_per_cpu(here, jobs, t)}" for t in names))
    print(f"per trial, on 1 Dask worker:  {per_trial(one)}")
    print(f"per trial, on 2 Dask workers: {per_trial(two)}")
    n = len(jobs)
    rate = {k: n / wall * 60.0 for k, wall in (("here", here_wall), ("1", one_wall), ("2", two_wall))}
    print(f"trials per minute: this process {rate['here']:.2f}, 1 worker {rate['1']:.2f}, 2 workers {rate['2']:.2f} "
          f"-> 2 workers / 1 = {rate['2'] / rate['1']:.2f}x (target >= 1.7x on 2 cores)")
    def at_once(done: dict[str, TrialDone], wall: float) -> str:
        return f"{sum(d.wall_s for d in done.values()) / wall:.2f}"

    print(f"trials running at once on average (trials' own wall / batch wall): 1 worker {at_once(one, one_wall)}, "
          f"2 workers {at_once(two, two_wall)}")
    print(f"cluster start-up (not in the rates): 1 worker {one_start:.1f} s, 2 workers {two_start:.1f} s")
    inside = sum(d.wall_s for d in one.values())
    overhead = (one_wall - inside) / n
    print(f"Dask overhead per trial (1 worker: batch wall - trials' own wall, per trial): {overhead * 1e3:.0f} ms "
          f"= {overhead / (inside / n) * 100:.2f}% of a trial's wall time (target < 2%)")
    print(f"a trial on a Dask worker against in this process (same seeds): wall "
          f"{inside / sum(d.wall_s for d in here.values()):.2f}x")

    def metrics(done: dict[str, TrialDone]) -> list[dict]:
        return [done[job.key].report.live.to_json_dict() for job in jobs]

    equal = metrics(here) == metrics(one) == metrics(two)
    print(f"tables equal metric for metric (this process, 1 worker, 2 workers): {equal}")
    shape = kind_of(study).table
    print(shape([two[job.key].report for job in jobs]))
    return 0 if equal and inside else 1


if __name__ == "__main__":
    raise SystemExit(main())
