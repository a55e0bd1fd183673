"""``rakectl fuzz``: the closed-loop safety campaign from the command line."""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from rakectl.bench.sections import markdown_table
from rakectl.cli.usage import Parser
from rakectl.limits import FORCE_LIMIT_N
from rakectl.sim import chain
from rakectl.sim.campaign import campaign, declares_sites, merged, replay
from rakectl.sim.case_files import read_case_file
from rakectl.sim.cases import Family
from rakectl.sim.compare import compare, describe, read_results
from rakectl.sim.compare import summary as compare_summary
from rakectl.sim.injection import FaultyRakeLoop
from rakectl.sim.parallel import executor_for
from rakectl.sim.plants import BASE_COLUMNS
from rakectl.sim.progress import Progress
from rakectl.sim.results import RESULTS_FILE, WORST_CASE_FILE, CaseResult, Report

FORCES_PLOT = "forces.png"  # --plot's figure, in --out
EDGE_PLOT = "edge.png"  # --plot's second figure for the edge family, in --out


def _parser() -> argparse.ArgumentParser:
    p = Parser(
        prog="rakectl fuzz",
        description="Closed-loop safety campaign: random grounds, commands (lanes, hostile "
        "plunges and strokes, jogs at full speed) and faults (lost feedback and commands, "
        "drive faults, controller stalls, SIGKILL) through the simulated robot, half with "
        "the force supervision, half the clamp alone. Exit status 0 only if no tick's true "
        f"vertical tip force exceeded {FORCE_LIMIT_N:g} N, no force on a mine (plate or "
        "side) did and no mine fired; 1 otherwise (also when a replayed case does not "
        "reproduce); 2 on usage errors.")
    p.add_argument("--scenarios", type=int, default=100, help="number of cases (default 100)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    p.add_argument("--family", choices=[str(f) for f in Family], default=str(Family.RANDOM),
                   help="how cases are drawn: random (default: everything an operator can "
                   "command, objects anywhere), edge (plunges along an object's side into "
                   "its rounded top edge) or mapped (lanes with their sites declared and the "
                   "descent limiter on, down beside a buried object; a lane held by the limit "
                   "is asked again until the case ends)")
    p.add_argument("--declared-site", action="store_true",
                   help="declare each case's site as its operator would (its strongest soil, "
                   "its surveyed surface) and run with the descent limiter on "
                   "(descent.enforce; docs/safety.md); a site whose soil leaves the limiter "
                   "no step is refused, as the daemon refuses it at load, and counted")
    p.add_argument("--first", type=int, default=0,
                   help="index of the first case (default 0): a large campaign in parts")
    p.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    p.add_argument("--json", action="store_true", help="one JSON object on the last line")
    p.add_argument("--out", type=Path, default=None,
                   help=f"directory for {WORST_CASE_FILE} and {RESULTS_FILE} (each case's "
                   "result as it finishes; cases already there are not run again: a "
                   "campaign resumes, or is run in parts into one directory; results of "
                   "another version of the code there are refused)")
    p.add_argument("--plot", action="store_true",
                   help=f"with --out: also write OUT/{FORCES_PLOT} (how many cases read at least "
                   "each force, by what carried it, by fault and by command, against the "
                   "limit; the [plot] extra); for the edge family's cases also OUT/"
                   f"{EDGE_PLOT} (each case's side force on its object against the soil's "
                   "cutting resistance at the object's edge). On a finished --out it runs "
                   "nothing and plots")
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT|local:N",
                   help="run the cases on a Dask cluster (the [cluster] extra): an existing "
                   "scheduler, or local:N to start N worker processes here; default: "
                   "--workers local processes")
    p.add_argument("--replay", type=Path, default=None,
                   help="re-run a case file (a worst case, or tests/data/fuzz/*.json)")
    p.add_argument("--trace", default=None, metavar="INDEX|CASE.json",
                   help="run one case (case INDEX of --seed and --family, or a case file) "
                   "and show, substep by substep, where an object pushed the tines hardest "
                   "along the reach: the object's force, the soil's and the mount's, what "
                   "the massless tines' balance leaves over, and the soil's cutting "
                   "resistance at their cut; then the largest vertical reading against what "
                   "the mount carried into the ground (rakectl.sim.trace)")
    p.add_argument("--compare", type=Path, default=None, metavar="DIR",
                   help="after the campaign, compare its results case by case with the same "
                   "cases in an earlier run's --out DIR (another chain's): how many differ, "
                   "which outcomes changed, the largest moves of each force "
                   "(rakectl.sim.compare); with a finished --out it runs nothing")
    p.add_argument("--merge", type=Path, nargs="+", default=None, metavar="DIR",
                   help="run nothing: report the finished campaigns in these --out "
                   "directories as one (several seeds, or one seed run in parts): the "
                   "largest forces, the cases over the limit and the table by command, "
                   "fault and supervision; exit status as a campaign's. A case found in "
                   "two of them, or results of two versions of the code, are refused. "
                   "With --plot --out DIR, the figures of all of them together are written "
                   "to DIR")
    p.add_argument("--mcap", type=Path, default=None, metavar="OUT.mcap",
                   help="with --replay: record the replay as MCAP (and its telemetry as "
                   "OUT.csv next to it; the [view] extra; docs/viewer.md)")
    return p


def banner(args: argparse.Namespace, runs_on: str, physics: str) -> str:
    """The line a campaign starts with: which cases, how drawn, on what."""
    declared = declares_sites(Family(args.family), args.declared_site)
    site = ", sites declared, descent limiter on" if declared else ""
    return (f"fuzz: cases {args.first}..{args.first + args.scenarios - 1} of seed "
            f"{args.seed} ({args.family}{site}) on {runs_on}; {physics}; code {chain.digest()}")


TABLE_COLUMNS = ("cases", "n", "ground, largest (N)", "mine, plate or side, largest (N)",
                 "stone side, largest (N)", "watchdog trips", "unsafe")


def kind_table(by_kind: dict[str, dict[str, float | int]]) -> list[str]:
    """The campaign by command kind, fault kind and supervision, as docs/safety-log.md
    tables it (markdown): a case counts in its kind's row, in each fault row it injects
    and in one supervision row; ``refused`` sites get a column where there are any."""
    refused = any(k["refused"] for k in by_kind.values())
    rows = [(group, str(k["cases"]), f"{k['f_true_z_max_n']:.1f}", f"{k['f_mine_max_n']:.1f}",
             f"{k['f_stone_side_max_n']:.1f}", str(k["watchdog_trips"]), str(k["unsafe"]),
             *((str(k["refused"]),) if refused else ())) for group, k in by_kind.items()]
    return markdown_table((*TABLE_COLUMNS, "refused") if refused else TABLE_COLUMNS, rows)


def human(report: Report) -> str:
    s = report.summary()
    if s["resumed"] == s["scenarios"]:  # nothing ran: no rate to give
        ran = f"{s['scenarios']} scenarios, all read back from an earlier run (none ran)"
    else:
        resumed = f", {s['resumed']} of them read back from an earlier run" \
            if s["resumed"] else ""
        ran = (f"{s['scenarios']} scenarios in {s['wall_time_s']:.0f} s "
               f"({s['scenarios_per_min']:.0f}/min{resumed})")
    lines = [ran, f"code that ran them: {chain.counted(r.chain for r in report.results)}",
             f"largest true vertical force on the ground: {s['f_true_z_max_n']:.1f} N "
             f"(limit {FORCE_LIMIT_N:g} N)",
             f"largest force on a mine: plate {s['f_mine_plate_max_n']:.1f} N, side "
             f"{s['f_mine_side_max_n']:.1f} N (limit {FORCE_LIMIT_N:g} N)",
             f"largest side force on a stone: {s['f_stone_side_max_n']:.1f} N, on a root: "
             f"{s['f_root_side_max_n']:.1f} N",
             f"ticks over the limit: {s['ticks_over_limit']}; unsafe cases: "
             f"{s['unsafe_cases']}; mine activations: {s['mine_activations']}",
             f"controller faults: {s['controller_faults']}; drive watchdog trips: "
             f"{s['watchdog_trips']}"]
    if s["refused_sites"]:
        lines.append(f"sites refused at load (their declared soil leaves the descent limiter "
                     f"no step; nothing ran): {s['refused_sites']}")
    lines += kind_table(s["by_kind"])
    lines += [f"unsafe: {case}" for case in s["over_limit"]]
    lines.append(f"worst: {s['worst_case']} → ground {report.worst.f_true_z_max_n:.1f} N, "
                 f"mine {report.worst.f_mine_max_n:.1f} N")
    whole = report.directory
    if whole is not None:
        lines.append(f"the directory holds {len(whole.results)} results in all ("
                     f"{merged_title(whole.results)}): unsafe {len(whole.unsafe)}, worst "
                     f"{whole.summary()['worst_case']} → ground {whole.worst.f_true_z_max_n:.1f} N,"
                     f" mine {whole.worst.f_mine_max_n:.1f} N")
    if report.worst_case_path:
        lines.append(f"worst case written to {report.worst_case_path}"
                     + (" (the directory's)" if whole is not None else ""))
    return "\n".join(lines)


def _replay_main(path: Path, as_json: bool, mcap: Path | None = None) -> int:
    rows: list[tuple[float, ...]] = []
    columns: list[tuple[str, ...]] = []

    def record(loop: FaultyRakeLoop) -> None:
        if not columns:
            columns.append(("t_s", *BASE_COLUMNS, *loop.columns))
        rows.append((len(rows) * loop.dt_s, *loop.row()))

    if mcap is not None:
        from rakectl.view.record import telemetry_to_mcap  # fail before the work

        if mcap.suffix != ".mcap":
            print(f"rakectl: error: fuzz: --mcap {mcap}: give a file ending in .mcap (its "
                  "telemetry goes next to it as .csv)", file=sys.stderr)
            return 2
    try:
        case, _ = read_case_file(path)  # a file that is not a case: refused before running
    except (OSError, ValueError, KeyError, TypeError) as e:
        print(f"rakectl: error: fuzz: --replay {path}: not a case file ({e})", file=sys.stderr)
        return 2
    now, recorded = replay(path, record if mcap is not None else None)
    if mcap is not None:
        from rakectl.cli.view import boxes

        telemetry = mcap.with_suffix(".csv")
        mcap.parent.mkdir(parents=True, exist_ok=True)
        with telemetry.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(columns[0])
            writer.writerows(rows)
        telemetry_to_mcap(telemetry, mcap, objects=boxes(case.ground.objects))
        print(f"replay {path}: recorded as {mcap} (telemetry {telemetry})", file=sys.stderr)
    same = recorded is None or now.same_as(recorded)
    code = "" if recorded is None or recorded.chain == now.chain else \
        f" (recorded on code {chain.name(recorded.chain)}, run on {now.chain})"
    out = {"replayed": str(path), "same": same, "safe": now.safe, **now.to_dict(),
           "recorded_chain": None if recorded is None else recorded.chain}
    print(json.dumps(out) if as_json else
          f"replay {path}: ground {now.f_true_z_max_n:.1f} N, mine {now.f_mine_max_n:.1f} N, "
          f"{now.ticks_over_limit} ticks over, mine activated {now.mine_activated}; "
          + ("no recorded result" if recorded is None else
             "same result" if same else "DIFFERENT result") + code)
    return 0 if same and now.safe else 1


def _trace_main(args: argparse.Namespace) -> int:
    from rakectl.sim.campaign import generated_case
    from rakectl.sim.trace import describe, summary, trace_case

    what = args.trace
    if what.isdigit():
        case = generated_case(args.seed, int(what), Family(args.family), args.declared_site)
    else:
        try:
            case, _ = read_case_file(Path(what))
        except (OSError, ValueError, KeyError, TypeError) as e:
            print(f"rakectl: error: fuzz: --trace {what}: neither a case index (a whole "
                  f"number) nor a case file ({e})", file=sys.stderr)
            return 2
    trace = trace_case(case)
    print("\n".join(describe(trace)))
    if args.json:
        print(json.dumps(summary(trace)))
    return 0 if trace.result.safe else 1


def _plot(report: Report, out_dir: Path, title: str) -> None:
    """``--plot``: OUT/forces.png, and where the report holds edge cases OUT/edge.png (their
    side forces against the soil's resistance at the objects' edges)."""
    from rakectl.config.settings import ClampSettings
    from rakectl.sim.edge import edge_readings
    from rakectl.sim.plot import plot_campaign, plot_edge_resistance

    plot_campaign(report, out_dir / FORCES_PLOT, title)
    print(f"fuzz: plot written to {out_dir / FORCES_PLOT}", file=sys.stderr)
    readings = edge_readings(report.results)
    if readings:
        clamp = ClampSettings()
        plot_edge_resistance(readings, out_dir / EDGE_PLOT,
                             clamp.force_limit_n * clamp.model_margin, title)
        print(f"fuzz: plot written to {out_dir / EDGE_PLOT}", file=sys.stderr)


def merged_title(results: Sequence[CaseResult]) -> str:
    """What a merged report's plots are titled with: its seeds, families and cases."""
    seeds = sorted({r.seed for r in results})
    families = sorted({r.family + (", sites declared" if r.declared_site else "")
                       for r in results})
    return (f"seed{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))} "
            f"({'; '.join(families)}), merged")


# a campaign's own options, which --replay and --trace (one case) do not take
_NOT_WITH_ONE_CASE = ("scenarios", "first", "workers", "scheduler", "out", "plot", "compare")
# what chooses or runs cases: a merge reads the cases its directories hold
_NOT_WITH_MERGE = ("scenarios", "seed", "first", "family", "declared_site", "workers",
                   "scheduler", "compare", "replay", "trace", "mcap")


def _given(args: argparse.Namespace, names: Sequence[str]) -> list[str]:
    """Which of these options ``args`` gives other than their defaults, as flags."""
    defaults = _parser().parse_args([])
    return ["--" + name.replace("_", "-") for name in names
            if getattr(args, name) != getattr(defaults, name)]


def _merge_main(args: argparse.Namespace) -> int:
    given = _given(args, _NOT_WITH_MERGE)
    if given:
        print(f"rakectl: error: fuzz: --merge reads finished campaigns and runs nothing; "
              f"{', '.join(given)} cannot go with it", file=sys.stderr)
        return 2
    if args.plot != (args.out is not None):
        print("rakectl: error: fuzz: --merge takes --plot and --out together (the figures are "
              "written to --out DIR) or neither", file=sys.stderr)
        return 2
    if args.plot and (args.out / RESULTS_FILE).exists():
        print(f"rakectl: error: fuzz: --merge --out {args.out} holds a campaign's results: its "
              "plots are that campaign's; write the merged ones elsewhere", file=sys.stderr)
        return 2
    if args.plot:
        from rakectl.sim.plot import pyplot

        pyplot()  # matplotlib missing: said now, before reading the runs
    try:
        report, counts = merged(args.merge)
    except ValueError as e:
        print(f"rakectl: error: fuzz: --merge: {e}", file=sys.stderr)
        return 2
    for out_dir, n in counts.items():
        print(f"merged: {n} results from {out_dir}")
    print(f"merged: {merged_title(report.results)}: each table row counts them together")
    if args.plot:
        args.out.mkdir(parents=True, exist_ok=True)
        _plot(report, args.out, merged_title(report.results))
    print(human(report))
    if args.json:
        print(json.dumps({**report.summary(),
                          "merged": {str(d): n for d, n in counts.items()}}))
    return 0 if report.safe else 1


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.merge is not None:
        return _merge_main(args)
    if args.mcap is not None and args.replay is None:
        print("rakectl: error: fuzz: --mcap records a --replay: give the case file",
              file=sys.stderr)
        return 2
    if args.trace is not None and args.replay is not None:
        print("rakectl: error: fuzz: --trace and --replay each run one case: give one of them",
              file=sys.stderr)
        return 2
    if args.seed < 0:  # numpy's generator takes none (a traceback before)
        print(f"rakectl: error: fuzz: --seed must be >= 0, got {args.seed}", file=sys.stderr)
        return 2
    if args.replay is not None or args.trace is not None:  # one case: a campaign's options
        ignored = ("seed", "family", "declared_site") if args.replay is not None else ()
        given = _given(args, (*_NOT_WITH_ONE_CASE, *ignored))  # it would seem run with
        if given:
            one = "--replay" if args.replay is not None else "--trace"
            print(f"rakectl: error: fuzz: {one} runs one case; {', '.join(given)} cannot go "
                  "with it", file=sys.stderr)
            return 2
    if args.replay is not None:
        return _replay_main(args.replay, args.json, args.mcap)
    if args.trace is not None:
        return _trace_main(args)
    for flag, value, least in (("--scenarios", args.scenarios, 1),
                               ("--workers", args.workers, 1), ("--first", args.first, 0)):
        if value < least:
            print(f"rakectl: error: fuzz: {flag} must be >= {least}, got {value}",
                  file=sys.stderr)
            return 2
    if args.plot and args.out is None:
        print("rakectl: error: fuzz: --plot needs --out DIR (the plot is written there)",
              file=sys.stderr)
        return 2
    if args.out is not None and args.out.exists() and not args.out.is_dir():
        print(f"rakectl: error: fuzz: --out {args.out} is not a directory", file=sys.stderr)
        return 2
    if args.plot:
        from rakectl.sim.plot import pyplot

        pyplot()  # matplotlib missing: said now, not after the campaign
    earlier: list[CaseResult] = []
    if args.compare is not None:  # an earlier run that is not there: said before running
        try:
            earlier = read_results(args.compare)
        except OSError as e:
            print(f"rakectl: error: fuzz: --compare {args.compare}: no campaign results there "
                  f"({e})", file=sys.stderr)
            return 2
        if not earlier:
            print(f"rakectl: error: fuzz: --compare {args.compare}: its {RESULTS_FILE} holds no "
                  "case's result", file=sys.stderr)
            return 2
        sites = declares_sites(Family(args.family), args.declared_site)
        wanted = range(args.first, args.first + args.scenarios)
        if not any(r.seed == args.seed and r.index in wanted and r.family == args.family
                   and r.declared_site == sites for r in earlier):
            print(f"rakectl: error: fuzz: --compare {args.compare} holds none of these cases "
                  f"(it holds {merged_title(earlier).removesuffix(', merged')}): nothing to "
                  "compare with", file=sys.stderr)
            return 2
    executor = executor_for(args.scheduler, args.workers)
    try:
        print(banner(args, executor.describe(), executor.physics()), file=sys.stderr)
        report = campaign(args.scenarios, args.seed, args.workers, args.out, Progress("fuzz"),
                          first=args.first, executor=executor, family=Family(args.family),
                          declared_site=args.declared_site)
    except chain.MixedChains as e:
        print(f"rakectl: error: fuzz: {e}", file=sys.stderr)
        return 2
    finally:
        executor.close()
    if args.plot:
        declared = ", sites declared" if declares_sites(Family(args.family),
                                                        args.declared_site) else ""
        span = f"seed {args.seed}, cases {args.first}..{args.first + args.scenarios - 1}"
        if report.directory is not None:  # the plots stand for the whole directory
            _plot(report.directory, args.out, merged_title(report.directory.results))
        else:
            _plot(report, args.out, f"{span} ({args.family}{declared})")
    print(human(report))
    figures = report.summary()
    if args.compare is not None:
        comparison = compare(report.results, earlier)
        print("\n".join(describe(comparison, str(args.compare))))
        figures["compare"] = {"against": str(args.compare), **compare_summary(comparison)}
    if args.json:
        print(json.dumps(figures))
    return 0 if report.safe else 1
