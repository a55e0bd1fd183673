"""The ``rakectl`` command line: the composition root for offline work.

Errors are one line on stderr and a non-zero exit status: 2 for bad usage,
configuration or input file (a bus trace to replay), 1 for any other failure.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from rakectl.errors import ConfigError, RakeError, TraceError

if TYPE_CHECKING:
    from rakectl.sim.scenario import Scenario
    from rakectl.sim.simulate import SimulationResult

PASS_THROUGH = ("emulator", "fuzz")  # sub-commands whose options their own parser reads
EXIT_FAILURE = 1
EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors raise instead of exiting from library code."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise ConfigError(f"{self.prog}: {message}")


def _add_simulate(sub: argparse._SubParsersAction[_Parser]) -> None:
    p = sub.add_parser("simulate", help="run a scenario in simulated time")
    p.add_argument("scenario", type=Path, help="scenario YAML file (see config/scenarios/)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one option, e.g. --set estimator.delay_s=0.02 (repeatable)")
    p.add_argument("--out", type=Path, required=True, help="directory for telemetry and summary")
    p.add_argument("--plot", action="store_true", help="also write DIR/plot.png")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    p.add_argument("--mcap", action="store_true", help="also write DIR/telemetry.mcap (plant "
                   "rake; the [view] extra)")


def _build_parser() -> tuple[_Parser, dict[str, Callable[[argparse.Namespace], int]]]:
    from rakectl.api import operator as cli_ops
    from rakectl.api import survey as cli_survey

    parser = _Parser(prog="rakectl", description=__doc__.splitlines()[0] if __doc__ else None)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    _add_simulate(sub)
    run = sub.add_parser("run", help="the 1 kHz control daemon (the service)")
    run.add_argument("--config", type=Path, help="YAML configuration (e.g. config/rakectl.yaml)")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                     help="override one option (repeatable)")
    sub.add_parser("emulator", help="the emulated drives and physics (bench set-ups); "
                   "its options: rakectl emulator --help", add_help=False)
    client = _Parser(add_help=False)
    client.add_argument("--socket", help="the daemon's command socket")
    client.add_argument("--json", action="store_true", help="the reply as JSON on stdout")
    ops = cli_ops.add_parsers(sub, client)
    ops.update(cli_survey.add_parser(sub, client))
    sub.add_parser("config-docs", help="print the configuration reference (Markdown)")
    sub.add_parser("api-docs", help="print the command API reference (Markdown)")
    sub.add_parser("fuzz", help="closed-loop safety campaign over random scenarios; "
                   "its options: rakectl fuzz --help", add_help=False)
    demo = sub.add_parser("demo", help="the whole system on an emulated bench: find a mine")
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="logs, truth, plot")
    demo.add_argument("--json", action="store_true", help="the summary as JSON on the last line")
    demo.add_argument("--drive-profile", choices=("cia402", "roboteq"), default="cia402",
                      help="the drives the emulator plays and the daemon drives "
                      "(drives.profile of both): the project's own (cia402, default) or "
                      "Roboteq-class motor controllers (roboteq)")
    files = sub.add_parser("files", help="where the example configurations and systemd "
                           "files are (installed with the package), or copy them")
    files.add_argument("--copy", type=Path, metavar="DIR", help="copy config/ and systemd/ "
                       "into DIR (refused if DIR already holds them)")
    _add_bench(sub)
    comp = sub.add_parser("compile", help="compile the emulator's physics with mypyc (the "
                          "[fast] extra and a C compiler): the same results, 2.6x less CPU a case; "
                          "used by every process started after it, until the sources change")
    comp.add_argument("--force", action="store_true", help="build again even if built")
    from rakectl.cli import drives as cli_drives
    from rakectl.cli import replay as cli_replay
    from rakectl.cli import view as cli_view

    cli_view.add_parsers(sub)
    cli_drives.add_parser(sub)
    cli_replay.add_parser(sub)
    return parser, ops


def _add_bench(sub: argparse._SubParsersAction[_Parser]) -> None:
    bench = sub.add_parser("bench", help="benchmarks that print figures (default: the "
                           "micro-benchmarks; --all: everything, written to BENCHMARKS.md)")
    what = bench.add_mutually_exclusive_group()
    what.add_argument("--all", action="store_true", help="loop latency vs cyclictest, "
                      "cross-process bus, per-tick stages, excavation; writes "
                      "REPORT/BENCHMARKS.md and one plot per soil")
    what.add_argument("--loop", action="store_true",
                      help="the daemon's loop on the emulated bench against cyclictest")
    what.add_argument("--tick", action="store_true", help="the daemon's tick, stage by stage")
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
                       help="campaign cases to time (--campaign, --all)")
    bench.add_argument("--workers", type=int, default=2, help="processes for excavation runs")
    bench.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT|local:N",
                       help="run the excavation runs on a Dask cluster (the [cluster] extra): "
                       "an existing scheduler, or local:N to start N worker processes here; "
                       "default: --workers local processes")
    bench.add_argument("--out", type=Path, default=Path("out/bench-loop"),
                       help="scratch: the loop benchmark's logs")
    bench.add_argument("--report", type=Path, default=None, help="where --all writes "
                       "BENCHMARKS.md (--excavation, --profiles and --campaign their sections) "
                       "and --all/--excavation the plots (default: bench, out/bench with "
                       "--quick)")


def _cmd_simulate(args: argparse.Namespace) -> int:
    from rakectl.config.loader import load_settings
    from rakectl.sim.progress import Progress
    from rakectl.sim.scenario import Scenario
    from rakectl.sim.simulate import run, write_results

    settings = load_settings(args.scenario, args.overrides, root=Scenario)
    if args.plot:
        from rakectl.sim.plot import pyplot

        pyplot()  # fail before the work, not after it
    if args.mcap:
        from rakectl.sim.scenario import PlantKind
        from rakectl.view.record import telemetry_to_mcap  # fail before the work

        if settings.plant.kind is not PlantKind.RAKE:
            raise ConfigError("simulate: --mcap needs plant kind rake (the rake's pose)")
    result = run(settings, progress=Progress(f"simulating {args.scenario.name}"))
    write_results(result, args.out)
    if args.plot:
        _plot(settings, result, args.out / "plot.png", args.scenario.name)
    if args.mcap:
        from rakectl.cli.view import boxes

        telemetry_to_mcap(args.out / "telemetry.csv", args.out / "telemetry.mcap",
                          objects=boxes(settings.emulator.ground.objects))
    summary = result.summary()
    if args.json:
        print(json.dumps(summary))
    else:
        for key, value in summary.items():
            print(f"{key:>24}: {value:.6g}" if isinstance(value, float) else f"{key:>24}: {value}")
        print(f"{'written to':>24}: {args.out}")
    return 0


def _plot(settings: Scenario, result: SimulationResult, path: Path, title: str) -> None:
    from rakectl.sim.plot import plot_lane, plot_paper_panels
    from rakectl.sim.scenario import PlantKind, TrajectoryKind

    if settings.plant.kind is PlantKind.RAKE and settings.trajectory.kind is TrajectoryKind.LANE:
        mines = [(m.reach_m, m.depth_m, m.width_m, m.thickness_m)
                 for m in settings.emulator.ground.objects.mines]
        plot_lane(result, path, mines, title)
    else:
        plot_paper_panels(result, path, title)


def _cmd_config_docs(args: argparse.Namespace) -> int:
    from rakectl.cli.docs import configuration_reference

    print(configuration_reference())
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from rakectl.bench.micro import bench_controller_step, bench_emulator_step

    if not 1 <= args.workers <= 64:
        raise ConfigError("bench: --workers must be in [1, 64]")
    if not 1 <= args.cases <= 100_000:
        raise ConfigError("bench: --cases must be in [1, 100000]")
    if args.scheduler is not None:
        from rakectl.sim.parallel import local_workers

        if not (args.all or args.excavation):
            raise ConfigError("bench: --scheduler is for the excavation runs (--excavation, "
                              "--all)")
        local_workers(args.scheduler)  # a bad one is named now, not after the other parts
    report = args.report or Path("bench" if (args.all or args.excavation or args.campaign)
                                 and not args.quick else "out/bench")
    if args.all or args.excavation or args.tick:
        return _cmd_bench_parts(args, report)
    if args.profiles:
        return _cmd_bench_profiles(args, Path(args.report or "bench"))
    if args.campaign:
        return _cmd_bench_campaign(args, report)
    if args.loop:
        from rakectl.bench.loop import run_bench

        if not 1.0 <= args.seconds <= 3600.0:
            raise ConfigError("bench: --seconds must be in [1, 3600]")
        print(run_bench(args.seconds, args.out))
        return 0
    if args.ticks < 1000:
        raise ConfigError("bench: --ticks must be >= 1000")
    from rakectl.bench.hot_path import bench_hot_path

    print(bench_controller_step(args.ticks))
    print(bench_emulator_step(max(1000, args.ticks // 50)))
    print(bench_hot_path(max(1000, args.ticks // 10)))
    return 0


def _cmd_bench_profiles(args: argparse.Namespace, report: Path) -> int:
    from rakectl.bench.hot_path import bench_hot_path, hot_path_section, write_hot_path_section
    from rakectl.bench.report import BENCHMARKS_FILE, git_revision

    if args.ticks < 1000:
        raise ConfigError("bench: --ticks must be >= 1000")
    text = bench_hot_path(args.ticks // 10)
    print(text)
    path = report / BENCHMARKS_FILE
    started = time.strftime("%Y-%m-%d %H:%M %Z")
    write_hot_path_section(path, hot_path_section("rakectl " + " ".join(args.argv), started,
                                                  git_revision(), text))
    print(f"written: section (e) of {path}")
    return 0


def _cmd_bench_campaign(args: argparse.Namespace, report: Path) -> int:
    from rakectl.bench.report import BENCHMARKS_FILE, git_revision
    from rakectl.bench.throughput import (
        compare_physics,
        format_comparison,
        write_throughput_section,
    )

    started = time.strftime("%Y-%m-%d %H:%M %Z")
    figures = compare_physics(cases=args.cases, progress=_echo_progress)
    print(format_comparison(figures))
    path = report / BENCHMARKS_FILE
    write_throughput_section(path, "rakectl " + " ".join(args.argv), started, git_revision(),
                             figures)
    print(f"written: section (f) of {path}")
    return 0


def _cmd_bench_parts(args: argparse.Namespace, report: Path) -> int:
    tick_ticks = 2000 if args.quick else max(1000, args.ticks // 10)
    if args.tick:
        from rakectl.bench.tick import bench_tick, format_tick

        print(format_tick(bench_tick(tick_ticks)))
        return 0
    if args.excavation:
        from rakectl.bench.report import excavate, format_excavation, git_revision, write_excavation
        from rakectl.sim.plot import pyplot

        pyplot()  # fail before the work, not after it
        started = time.strftime("%Y-%m-%d %H:%M %Z")
        result = excavate(args.scheduler, args.workers, args.quick, _echo_progress)
        print(format_excavation(result))
        path = write_excavation(result, report, "rakectl " + " ".join(args.argv), started,
                                git_revision())
        print(f"written: section (d) of {path} and the plots next to it")
        return 0
    from rakectl.bench.report import BenchOptions, run_all
    from rakectl.sim.plot import pyplot

    pyplot()
    seconds = 5.0 if args.quick else args.seconds
    if not 1.0 <= seconds <= 3600.0:
        raise ConfigError("bench: --seconds must be in [1, 3600]")
    command = "rakectl " + " ".join(args.argv)
    run_all(BenchOptions(command, seconds, tick_ticks, args.quick, args.workers, args.out,
                         report, args.scheduler, 6 if args.quick else args.cases),
            lambda line: print(line, flush=True))
    return 0


def _echo_progress(line: str) -> None:
    print(f"  {line}", file=sys.stderr, flush=True)


def _cmd_compile(args: argparse.Namespace) -> int:
    from drivers import compiled

    compiled.build(force=args.force, progress=lambda line: print(line, flush=True))
    print(f"compile: {compiled.MODE_ENV}=pure runs the Python physics instead")
    return 0


def _cmd_api_docs(args: argparse.Namespace) -> int:
    from rakectl.cli.docs import api_reference

    print(api_reference())
    return 0


def _cmd_fuzz(args: argparse.Namespace) -> int:
    from rakectl.cli.fuzz import main as fuzz_main

    return fuzz_main(args.rest)


def _cmd_demo(args: argparse.Namespace) -> int:
    from rakectl.sim.demo import run_demo

    return run_demo(args.out, args.json, args.drive_profile)


def _cmd_files(args: argparse.Namespace) -> int:
    import shutil

    from rakectl.config.files import shared_root

    root = shared_root()
    if args.copy is None:
        print(root)
        return 0
    for name in ("config", "systemd"):
        target = args.copy / name
        if target.exists():
            raise ConfigError(f"files: {target} exists; copy into an empty directory")
        shutil.copytree(root / name, target)
    print(f"files: config/ and systemd/ copied into {args.copy}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from rakectl.cli.view import cmd_view

    return cmd_view(args)


def _cmd_mcap(args: argparse.Namespace) -> int:
    from rakectl.cli.view import cmd_mcap

    return cmd_mcap(args)


def _cmd_drives(args: argparse.Namespace) -> int:
    from rakectl.cli.drives import cmd_drives

    return cmd_drives(args)


def _cmd_replay(args: argparse.Namespace) -> int:
    from rakectl.cli.replay import cmd_replay

    return cmd_replay(args)


def _cmd_run(args: argparse.Namespace) -> int:
    from rakectl.daemon.service import run

    return run(args.config, args.overrides)


def _cmd_emulator(args: argparse.Namespace) -> int:
    from drivers.cli import main as emulator_main

    return emulator_main(args.rest)


def main(argv: Sequence[str] | None = None) -> int:
    commands: dict[str, Callable[[argparse.Namespace], int]] = {
        "simulate": _cmd_simulate, "config-docs": _cmd_config_docs, "bench": _cmd_bench,
        "api-docs": _cmd_api_docs,
        "run": _cmd_run, "emulator": _cmd_emulator, "demo": _cmd_demo, "files": _cmd_files,
        "fuzz": _cmd_fuzz, "view": _cmd_view, "mcap": _cmd_mcap, "drives": _cmd_drives,
        "replay": _cmd_replay, "compile": _cmd_compile}
    try:
        parser, ops = _build_parser()
        args, extra = parser.parse_known_args(argv)
        args.argv = list(sys.argv[1:] if argv is None else argv)
        if args.command in PASS_THROUGH:  # these parse their own options
            args.rest = extra
        elif extra:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        return {**commands, **ops}[args.command](args)
    except (ConfigError, TraceError) as exc:
        print(f"rakectl: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (RakeError, OSError) as exc:  # OSError: TimeoutError and socket errors included
        print(f"rakectl: error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("rakectl: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
