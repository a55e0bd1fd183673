"""Which code ran a campaign's results (rakectl.sim.chain): each result records it; a
campaign does not add results to another version's, a merge does not table two versions
together, and a comparison or a replay says when the versions differ."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from rakectl.cli import fuzz as fuzz_cli
from rakectl.sim import campaign, case_files, chain, results
from rakectl.sim.cases import generate
from rakectl.sim.parallel import LocalExecutor

PINNED = Path(__file__).resolve().parents[1] / "data" / "pinned" / "fuzz-20261127-9702.jsonl"
PINNED_SEED, PINNED_FIRST, PINNED_CASES = 20261127, 9702, 60
OTHER = "0123456789ab"  # another version's digest


def _results_dir(where: Path, lines: Sequence[dict[str, Any]]) -> Path:
    where.mkdir()
    (where / results.RESULTS_FILE).write_text("".join(json.dumps(r) + "\n" for r in lines),
                                              encoding="utf-8")
    return where


def _pinned() -> list[dict[str, Any]]:
    """The pinned results, written before results recorded their code (its first line
    says on which commit they were run, and is no result)."""
    return [json.loads(line) for line in PINNED.read_text(encoding="utf-8").splitlines()[1:]]


@pytest.fixture(scope="module")
def one_case() -> tuple[Any, results.CaseResult]:
    case = generate(1, 0)  # a lane
    return case, campaign.run_case(case)


def test_the_chain_is_what_a_case_imports_at_any_depth() -> None:
    modules = chain.chain_modules(chain.PACKAGES)
    for name in ("rakectl.sim.campaign", "rakectl.sim.chain", "rakectl.core.clamp",
                 "rakectl.core.supervision", "rakectl.config.settings", "drivers.soil",
                 "drivers.mount_sideways", "rakectl.limits"):
        assert name in modules, name
    for name in ("rakectl.cli.fuzz", "rakectl.daemon.loop", "rakectl.drive.client",
                 "rakectl.view.record", "drivers.emulator"):
        assert name not in modules, name
    assert modules["drivers.soil"] == chain.PACKAGES["drivers"] / "soil.py"


def test_every_module_a_case_loads_is_in_the_chain() -> None:
    """What a fresh process holds of rakectl and drivers once it has run a case (the
    imports that ran, however made) is within the chain read from the sources."""
    script = ("import sys\nfrom rakectl.sim import campaign\nfrom rakectl.sim.cases import "
              "generate\ncampaign.run_case(generate(1, 0))\nprint(' '.join(sorted(m for m in "
              "sys.modules if m.split('.')[0] in ('rakectl', 'drivers'))))")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    loaded = set(done.stdout.split())
    assert "drivers.soil" in loaded and "rakectl.core.clamp" in loaded
    assert loaded <= set(chain.chain_modules(chain.PACKAGES)), \
        loaded - set(chain.chain_modules(chain.PACKAGES))


def test_the_digest_moves_with_the_chain_and_nothing_else(tmp_path: Path) -> None:
    copies = {name: tmp_path / name for name in chain.PACKAGES}
    for name, root in chain.PACKAGES.items():
        shutil.copytree(root, copies[name], ignore=shutil.ignore_patterns("__pycache__"))
    assert chain.source_digest(copies) == chain.digest()
    (copies["drivers"] / "notes.txt").write_text("not code\n")
    loop = copies["rakectl"] / "daemon" / "loop.py"  # the daemon: no case runs it
    loop.write_text(loop.read_text() + "\n")
    assert chain.source_digest(copies) == chain.digest()
    soil = copies["drivers"] / "soil.py"
    text = soil.read_text()
    soil.write_text(text + "\n")  # one byte more in the emulator's physics
    assert chain.source_digest(copies) != chain.digest()
    soil.write_text(text)
    assert chain.source_digest(copies) == chain.digest()
    clamp = copies["rakectl"] / "core" / "clamp.py"
    clamp.write_text(clamp.read_text().replace("import", "import", 1) + "# a comment\n")
    assert chain.source_digest(copies) != chain.digest()


def test_a_result_records_the_code_that_ran_it(one_case: tuple[Any, results.CaseResult]
                                               ) -> None:
    _, result = one_case
    assert result.chain == chain.digest() and len(result.chain) == 12
    assert result.same_as(dataclasses.replace(result, chain=OTHER))
    assert not result.same_as(dataclasses.replace(result, chain=OTHER, object_found=not
                                                  result.object_found))
    assert results.result_from_dict({**result.to_dict(), "chain": OTHER}).chain == OTHER
    old = result.to_dict()
    del old["chain"]  # a results file from before
    assert results.result_from_dict(old).chain == chain.UNRECORDED


def test_a_campaign_does_not_add_to_another_versions_results(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Cases left to run into a directory of unrecorded code's results: refused before
    any runs, the directory as it was; every case already there: read back, nothing
    runs, and the report says whose they are."""
    out = _results_dir(tmp_path / "out", _pinned())
    before = (out / results.RESULTS_FILE).read_bytes()
    with pytest.raises(chain.MixedChains) as refused:
        campaign.campaign(1, seed=PINNED_SEED, first=PINNED_FIRST + PINNED_CASES,
                          out_dir=out)
    assert str(refused.value) == (
        f"{out / results.RESULTS_FILE} holds results of other code: unrecorded (60 results); "
        f"this code is {chain.digest()}. One campaign's results come from one version: run "
        f"into a new --out (with --compare {out}, to see what the change moved)")
    assert (out / results.RESULTS_FILE).read_bytes() == before
    assert sorted(p.name for p in out.iterdir()) == [results.RESULTS_FILE]
    argv = ["--scenarios", "1", "--seed", str(PINNED_SEED), "--first",
            str(PINNED_FIRST + PINNED_CASES), "--out", str(out)]
    assert fuzz_cli.main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.splitlines()[-1] == f"rakectl: error: fuzz: {refused.value}"
    assert (out / results.RESULTS_FILE).read_bytes() == before

    report = campaign.campaign(PINNED_CASES, seed=PINNED_SEED, first=PINNED_FIRST, out_dir=out)
    assert report.resumed == PINNED_CASES and report.summary()["chains"] == [chain.UNRECORDED]
    assert (out / results.RESULTS_FILE).read_bytes() == before


class OtherCodeWorkers(LocalExecutor):
    """Local workers whose results come back stamped with another version's digest, as
    a cluster node running other code would send them."""

    def map_unordered(self, run: Callable[[Any], Any], jobs: Sequence[Any]) -> Iterator[Any]:
        for result in super().map_unordered(run, jobs):
            yield dataclasses.replace(result, chain=OTHER)


def test_a_worker_on_other_code_stops_the_campaign_before_its_result_is_kept(
        tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(chain.MixedChains, match=(
            rf"^case 1/0 ran on other code \({OTHER}; this process runs {chain.digest()}\): "
            "every worker must run this version$")):
        campaign.campaign(1, seed=1, out_dir=out, executor=OtherCodeWorkers(1))
    assert (out / results.RESULTS_FILE).read_text(encoding="utf-8") == ""


def test_a_merge_does_not_table_two_versions_together(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pinned = _pinned()
    a = _results_dir(tmp_path / "a", pinned[:25])
    b = _results_dir(tmp_path / "b", [{**r, "chain": OTHER} for r in pinned[25:]])
    assert fuzz_cli.main(["--merge", str(a), str(b)]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == (
        f"rakectl: error: fuzz: --merge: results of more than one version of the code: {a}: "
        f"unrecorded (25 results); {b}: {OTHER} (35 results) (one campaign's results come "
        "from one version)\n")
    same = _results_dir(tmp_path / "a-other", [{**r, "chain": OTHER} for r in pinned[:25]])
    assert fuzz_cli.main(["--merge", str(same), str(b), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert figures["scenarios"] == PINNED_CASES and figures["chains"] == [OTHER]


def test_a_replay_says_which_code_recorded_the_result(
        one_case: tuple[Any, results.CaseResult], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The same figures from another version: the same result, both versions named; a
    figure moved: a different result, exit 1."""
    case, result = one_case
    path = case_files.write_case(tmp_path / "case.json", case,
                                 dataclasses.replace(result, chain=OTHER))
    assert fuzz_cli.main(["--replay", str(path)]) == 0
    assert capsys.readouterr().out.endswith(
        f"; same result (recorded on code {OTHER}, run on {chain.digest()})\n")
    moved = dataclasses.replace(result, chain=OTHER, f_true_z_max_n=result.f_true_z_max_n + 1)
    case_files.write_case(path, case, moved)
    assert fuzz_cli.main(["--replay", str(path), "--json"]) == 1
    out = json.loads(capsys.readouterr().out)
    assert (out["same"], out["recorded_chain"], out["chain"]) == (False, OTHER, chain.digest())
