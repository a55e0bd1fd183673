"""``rakectl bench``: the benchmarks that print figures, and the report they write
(bench/BENCHMARKS.md, section by section)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from rakectl.errors import ConfigError


def add_parser(sub: argparse._SubParsersAction[Any]) -> None:
    """``rakectl bench``'s options."""
    bench = sub.add_parser("bench", help="benchmarks that print figures (default: the "
                           "micro-benchmarks; --all: everything, written to BENCHMARKS.md)")
    what = bench.add_mutually_exclusive_group()
    what.add_argument("--all", action="store_true", help="loop latency vs cyclictest, "
                      "cross-process bus, per-tick stages, excavation; writes "
                      "REPORT/BENCHMARKS.md and one plot per soil")
    what.add_argument("--loop", action="store_true",
                      help="the daemon's loop on the emulated bench against cyclictest; "
                      "rewrites its sections of REPORT/BENCHMARKS.md alone")
    what.add_argument("--tick", action="store_true", help="the daemon's tick, stage by "
                      "stage; rewrites its section of REPORT/BENCHMARKS.md alone")
    what.add_argument("--excavation", action="store_true", help="time to rake a lane to "
                      "depth in three soils: adaptive vs position control vs fixed speed; "
                      "rewrites its section of REPORT/BENCHMARKS.md alone")
    what.add_argument("--profiles", action="store_true", help="the drive client's hot path "
                      "per drive profile; rewrites its section of REPORT/BENCHMARKS.md alone")
    what.add_argument("--campaign", action="store_true", help="the safety campaign's speed "
                      "per core (--cases of its cases on one process); rewrites its section "
                      "of REPORT/BENCHMARKS.md alone")
    bench.add_argument("--ticks", type=int, default=200_000,
                       help="ticks to time (the tick stages use a tenth)")
    bench.add_argument("--seconds", type=float, default=60.0,
                       help="per phase of the loop benchmark (--loop, --all)")
    bench.add_argument("--quick", action="store_true", help="short phases and a short lane: "
                       "a check that it all runs, not figures")
    bench.add_argument("--cases", type=int, default=60,
                       help="campaign cases to time (--campaign, --all; --quick runs a few)")
    bench.add_argument("--workers", type=int, default=2, help="processes for excavation runs")
    bench.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT|local:N",
                       help="run the excavation runs on a Dask cluster (the [cluster] extra): "
                       "an existing scheduler, or local:N to start N worker processes here; "
                       "default: --workers local processes")
    bench.add_argument("--out", type=Path, default=Path("out/bench-loop"),
                       help="scratch: the loop benchmark's logs")
    bench.add_argument("--report", type=Path, default=None, help="where --all writes "
                       "BENCHMARKS.md (--loop, --tick, --excavation, --profiles and --campaign "
                       "their sections) and --all/--excavation the plots (default: bench, "
                       "out/bench with --quick)")


QUICK_CAMPAIGN_CASES = 4  # --campaign --quick: each physics runs this many, not --cases
QUICK_LOOP_S = 5.0  # --loop --quick, --all --quick: each phase of the loop benchmark


def cmd_bench(args: argparse.Namespace) -> int:
    from rakectl.bench.micro import bench_controller_step, bench_emulator_step

    if not 1 <= args.workers <= 64:
        raise ConfigError("bench: --workers must be in [1, 64]")
    if not 1 <= args.cases <= 100_000:
        raise ConfigError("bench: --cases must be in [1, 100000]")
    if args.ticks < 1000:  # every mode that times ticks: --tick took 0 and ran
        raise ConfigError("bench: --ticks must be >= 1000")
    if args.scheduler is not None:
        from rakectl.sim.parallel import local_workers

        if not (args.all or args.excavation):
            raise ConfigError("bench: --scheduler is for the excavation runs (--excavation, "
                              "--all)")
        local_workers(args.scheduler)  # a bad one is named now, not after the other parts
    report = args.report or Path("bench" if (args.all or args.excavation or args.campaign
                                             or args.loop or args.profiles or args.tick)
                                 and not args.quick else "out/bench")
    if args.all or args.excavation or args.tick:
        return _cmd_bench_parts(args, report)
    if args.profiles:
        return _cmd_bench_profiles(args, report)
    if args.campaign:
        return _cmd_bench_campaign(args, report)
    if args.loop:
        return _cmd_bench_loop(args, report)
    from rakectl.bench.hot_path import bench_hot_path

    print(bench_controller_step(args.ticks))
    print(bench_emulator_step(max(1000, args.ticks // 50)))
    print(bench_hot_path(max(1000, args.ticks // 10)))
    return 0


def _cmd_bench_profiles(args: argparse.Namespace, report: Path) -> int:
    from rakectl.bench.hot_path import bench_hot_path, hot_path_section, write_hot_path_section
    from rakectl.bench.report import BENCHMARKS_FILE, git_revision

    text = bench_hot_path(args.ticks // 10)
    print(text)
    path = report / BENCHMARKS_FILE
    started = time.strftime("%Y-%m-%d %H:%M %Z")
    write_hot_path_section(path, hot_path_section("rakectl " + " ".join(args.argv), started,
                                                  git_revision(), text))
    print(f"written: section (e) of {path}")
    return 0


def _cmd_bench_loop(args: argparse.Namespace, report: Path) -> int:
    from rakectl.bench.loop import format_loop, measure_loop
    from rakectl.bench.report import BENCHMARKS_FILE, git_revision, write_loop_section

    if not 1.0 <= args.seconds <= 3600.0:
        raise ConfigError("bench: --seconds must be in [1, 3600]")
    started = time.strftime("%Y-%m-%d %H:%M %Z")
    figures = measure_loop(QUICK_LOOP_S if args.quick else args.seconds, args.out)
    text = format_loop(figures)
    print(text)
    path = report / BENCHMARKS_FILE
    write_loop_section(path, figures, text, "rakectl " + " ".join(args.argv), started,
                       git_revision())
    print(f"written: sections (a) and (c) of {path}")
    return 0


def _cmd_bench_campaign(args: argparse.Namespace, report: Path) -> int:
    from rakectl.bench.report import BENCHMARKS_FILE, git_revision
    from rakectl.bench.throughput import (
        compare_physics,
        format_comparison,
        write_throughput_section,
    )

    started = time.strftime("%Y-%m-%d %H:%M %Z")
    cases = QUICK_CAMPAIGN_CASES if args.quick else args.cases  # --quick: a check it runs
    figures = compare_physics(cases=cases, progress=_echo_progress)
    print(format_comparison(figures))
    path = report / BENCHMARKS_FILE
    write_throughput_section(path, "rakectl " + " ".join(args.argv), started, git_revision(),
                             figures)
    print(f"written: section (f) of {path}")
    return 0


def _cmd_bench_parts(args: argparse.Namespace, report: Path) -> int:
    tick_ticks = 2000 if args.quick else max(1000, args.ticks // 10)
    if args.tick:
        from rakectl.bench.report import BENCHMARKS_FILE, git_revision, write_tick_section
        from rakectl.bench.tick import bench_tick, format_tick

        started = time.strftime("%Y-%m-%d %H:%M %Z")
        tick = bench_tick(tick_ticks)
        print(format_tick(tick))
        path = report / BENCHMARKS_FILE
        write_tick_section(path, tick, "rakectl " + " ".join(args.argv), started,
                           git_revision())
        print(f"written: section (b) of {path}")
        return 0
    if args.excavation:
        from rakectl.bench.excavation_text import format_excavation
        from rakectl.bench.report import excavate, git_revision, write_excavation
        from rakectl.sim.plot import pyplot

        pyplot(None)  # fail before the work, not after it (bench always plots)
        started = time.strftime("%Y-%m-%d %H:%M %Z")
        result = excavate(args.scheduler, args.workers, args.quick, _echo_progress)
        print(format_excavation(result))
        path = write_excavation(result, report, "rakectl " + " ".join(args.argv), started,
                                git_revision())
        print(f"written: section (d) of {path} and the plots next to it")
        return 0
    from rakectl.bench.report import BenchOptions, run_all
    from rakectl.sim.plot import pyplot

    pyplot(None)
    seconds = QUICK_LOOP_S if args.quick else args.seconds
    if not 1.0 <= seconds <= 3600.0:
        raise ConfigError("bench: --seconds must be in [1, 3600]")
    command = "rakectl " + " ".join(args.argv)
    run_all(BenchOptions(command, seconds, tick_ticks, args.quick, args.workers, args.out,
                         report, args.scheduler, 6 if args.quick else args.cases),
            lambda line: print(line, flush=True))
    return 0


def _echo_progress(line: str) -> None:
    print(f"  {line}", file=sys.stderr, flush=True)
