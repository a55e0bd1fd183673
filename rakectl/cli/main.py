"""The ``rakectl`` command line: the composition root for offline work.

Errors are one line on stderr and a non-zero exit status (:data:`EXIT_STATUSES`): 2 for
bad usage, a bad option value, configuration or input file (a bus trace to replay), 3
when the daemon cannot be reached or is lost, 1 for any other failure (the daemon
refused or failed).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import select
import signal
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from rakectl.cli.usage import Parser
from rakectl.errors import ConfigError, DaemonUnreachable, RakeError, TraceError

if TYPE_CHECKING:
    from rakectl.sim.scenario import Scenario
    from rakectl.sim.simulate import SimulationResult

PASS_THROUGH = ("emulator", "fuzz")  # sub-commands whose options their own parser reads
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_UNREACHABLE = 3
EXIT_SIGNAL = 128  # + the signal's number
DESCRIPTION = """\
The control of a demining robot's rake. `rakectl run` is the 1 kHz control daemon (the
service); the operator's commands (status, arm, jog, excavate, stop, estop, reset,
disarm, dump, survey) talk to it over its command socket (--socket, else
$RAKECTL_SOCKET, else the service's). The others are for set-up, the emulated bench
and offline work."""
EXIT_STATUSES = f"""\
exit status:
  0        done as asked (excavate: the lane reached its depth, held at the descent
           limit, or found an object; jog: its --duration, or Ctrl-C without one)
  {EXIT_FAILURE}        the daemon refused or failed, or the command did not complete: a lane
           stopped (rakectl stop, the force limit), a fault, an e-stop, a check
           before arming that failed
  {EXIT_USAGE}        bad usage or a bad option value, configuration or input file: nothing
           was sent
  {EXIT_UNREACHABLE}        the daemon cannot be reached, or was lost while the command followed
           it: check rakectl status
  {EXIT_SIGNAL}+N    ended by signal N: 130 Ctrl-C, 143 SIGTERM, 129 SIGHUP (jog and excavate
           stop the rake first), 141 when the reader of its output went away"""


def _add_simulate(sub: argparse._SubParsersAction[Parser]) -> None:
    p = sub.add_parser("simulate", help="run a scenario in simulated time")
    p.add_argument("scenario", type=Path, help="scenario YAML file (see config/scenarios/)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override one option, e.g. --set estimator.delay_s=0.02 (repeatable)")
    p.add_argument("--out", type=Path, required=True, help="directory for telemetry and summary "
                   "(an earlier run's plot or MCAP there is removed when this run makes none)")
    p.add_argument("--plot", action="store_true", help="also write DIR/plot.png")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    p.add_argument("--mcap", action="store_true", help="also write DIR/telemetry.mcap (plant "
                   "rake; the [view] extra)")


def _build_parser() -> tuple[Parser, dict[str, Callable[[argparse.Namespace], int]]]:
    from rakectl.api import operator as cli_ops
    from rakectl.api import survey as cli_survey
    from rakectl.cli import bench as cli_bench

    parser = Parser(prog="rakectl", description=DESCRIPTION, epilog=EXIT_STATUSES,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    _add_simulate(sub)
    run = sub.add_parser("run", help="the 1 kHz control daemon (the service)")
    run.add_argument("--config", type=Path, help="YAML configuration (e.g. config/rakectl.yaml)")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                     help="override one option (repeatable)")
    run.add_argument("--check", action="store_true",
                     help="check the configuration as the daemon loads it (the command "
                     "socket's path and group on this machine too), say what it would drive "
                     "and exit (0: it loads; 2: it does not, naming the key); opens nothing")
    run.add_argument("--user", metavar="NAME",
                     help="with --check: judge where the daemon writes, and that it can read "
                     "--config, as this user (default, run as root: rakectl, the service's "
                     "user, where it exists)")
    sub.add_parser("emulator", help="the emulated drives and physics (bench set-ups); "
                   "its options: rakectl emulator --help", add_help=False)
    client = Parser(add_help=False)
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
    files.add_argument("--copy", type=Path, metavar="DIR", help="copy config/, systemd/ "
                       "and the drives' EDS files (eds/) into DIR (refused if DIR already "
                       "holds them)")
    files.add_argument("--eds", action="store_true", help="print where the drives' EDS "
                       "files are (for a CANopen tool; docs/installation.md, section 6)")
    cli_bench.add_parser(sub)
    comp = sub.add_parser("compile", help="compile the emulator's physics with mypyc (the "
                          "[fast] extra and a C compiler): the same results, about 3x less "
                          "CPU a case (bench/BENCHMARKS.md section (f)); used by every "
                          "process started after it, until the sources change")
    comp.add_argument("--force", action="store_true", help="build again even if built")
    from rakectl.cli import drives as cli_drives
    from rakectl.cli import replay as cli_replay
    from rakectl.cli import view as cli_view

    cli_view.add_parsers(sub)
    cli_drives.add_parser(sub)
    cli_replay.add_parser(sub)
    return parser, ops


def _cmd_simulate(args: argparse.Namespace) -> int:
    from rakectl.config.loader import load_settings
    from rakectl.sim.progress import Progress
    from rakectl.sim.scenario import Scenario
    from rakectl.sim.simulate import run, write_results

    settings = load_settings(args.scenario, args.overrides, root=Scenario)
    if args.out.exists() and not args.out.is_dir():  # said before the work, not after it
        raise ConfigError(f"simulate: --out {args.out} is not a directory")
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
    for asked, name in ((args.plot, "plot.png"), (args.mcap, "telemetry.mcap")):
        if not asked:  # a previous run's, which this run's telemetry would sit beside
            (args.out / name).unlink(missing_ok=True)
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


DEMO_MODULES = ("matplotlib", "foxglove", "mcap", "msgpack")  # the [demo] extra's


def _cmd_demo(args: argparse.Namespace) -> int:
    missing = [name for name in DEMO_MODULES if importlib.util.find_spec(name) is None]
    if missing:
        raise RakeError(f"the demo needs the [demo] extra: pip install 'rakectl[demo]' "
                        f"(missing: {', '.join(missing)})")
    from rakectl.sim.demo import run_demo

    return run_demo(args.out, args.json, args.drive_profile)


def _cmd_files(args: argparse.Namespace) -> int:
    import shutil

    from rakectl.config.files import shared_root
    from rakectl.protocol.files import EDS_DIR

    if args.eds and args.copy is not None:
        raise ConfigError("files: --eds prints where the EDS files are; --copy copies them "
                          "too: give one of them")
    if args.eds:
        print(EDS_DIR)
        return 0
    root = shared_root()
    if args.copy is None:
        print(root)
        return 0
    sources = {"config": root / "config", "systemd": root / "systemd", "eds": EDS_DIR}
    if args.copy.exists() and not args.copy.is_dir():
        raise ConfigError(f"files: --copy {args.copy} is not a directory")
    for name in sources:
        if (args.copy / name).exists():
            raise ConfigError(f"files: {args.copy / name} exists; copy into an empty directory")
    for name, source in sources.items():
        shutil.copytree(source, args.copy / name)
    print(f"files: config/, systemd/ and eds/ copied into {args.copy}")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from rakectl.cli.bench import cmd_bench

    return cmd_bench(args)


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
    if args.check:
        from rakectl.cli.check import check_config

        return check_config(args.config, args.overrides, args.user)
    if args.user is not None:
        raise ConfigError("run --user: only with --check (the service's user is its unit's "
                          "User=)")
    from rakectl.daemon.service import run

    return run(args.config, args.overrides)


def _cmd_emulator(args: argparse.Namespace) -> int:
    from drivers.cli import main as emulator_main

    return emulator_main(args.rest, prog="rakectl emulator")


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
            parser.error(f"{args.command}: unrecognized arguments: {' '.join(extra)}")
        status = {**commands, **ops}[args.command](args)
        sys.stdout.flush()  # a reader gone is found here, not at the interpreter's exit
        return status
    except (ConfigError, TraceError) as exc:
        print(f"rakectl: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except DaemonUnreachable as exc:
        print(f"rakectl: error: {exc}", file=sys.stderr)
        return EXIT_UNREACHABLE
    except BrokenPipeError as exc:
        if _stdout_gone():  # `rakectl status | head -1`: quiet, as other Unix tools
            return EXIT_SIGNAL + signal.SIGPIPE
        print(f"rakectl: error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except (RakeError, OSError) as exc:  # OSError: TimeoutError and socket errors included
        print(f"rakectl: error: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print("rakectl: interrupted", file=sys.stderr)
        return EXIT_SIGNAL + signal.SIGINT


def _stdout_gone() -> bool:
    """Whether stdout is a pipe whose reader has gone; if so, stdout then points at
    /dev/null, so that the interpreter's exit does not write to it again."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        gone = any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, ValueError):  # no stdout, or not a file
        return False
    if gone:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    return gone


if __name__ == "__main__":
    sys.exit(main())
