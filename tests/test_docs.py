"""The documentation's promises: the generated references, the links and the README's
commands are the real ones."""

from __future__ import annotations

import re
from pathlib import Path

from rakectl.cli.docs import api_reference, configuration_reference

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
DOCS = ROOT / "docs"


def _generated(name: str, doc: str) -> str:
    text = (DOCS / doc).read_text()
    match = re.search(rf"{name}:start.*?-->\n(.*?)\n<!-- {name}:end", text, re.S)
    assert match, f"docs/{doc} lacks the generated {name}"
    return match.group(1).strip()


def test_configuration_reference_is_generated_from_the_declarations() -> None:
    assert _generated("config-reference", "configuration.md") == \
        configuration_reference().strip(), (
        "docs/configuration.md is stale: regenerate its block with `rakectl config-docs`"
    )


def test_api_reference_is_generated_from_the_command_table() -> None:
    assert _generated("api-reference", "api.md") == api_reference().strip(), (
        "docs/api.md is stale: regenerate its block with `rakectl api-docs`"
    )


def test_ci_runs_exactly_the_readme_test_command() -> None:
    blocks = re.findall(r"```sh\n(.*?)\n```", README, re.S)
    assert len(blocks) >= 2
    test_command = blocks[1].strip()
    assert test_command in (ROOT / ".ci" / "run").read_text()


def test_every_relative_link_resolves() -> None:
    """README.md and docs/*.md: every link to a file of the repository points at one."""
    for doc in (ROOT / "README.md", *sorted(DOCS.glob("*.md"))):
        for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", doc.read_text()):
            assert (doc.parent / target).exists(), f"{doc.name}: broken link {target}"


def test_the_readme_is_a_front_door() -> None:
    assert len(README.splitlines()) < 250


def test_the_installation_blocks_the_service_test_runs_are_there() -> None:
    """tests/service runs these blocks of docs/installation.md verbatim in its VM: each
    heading it names has one, the software block sets SRC, the bench block starts both
    services on vcan0."""
    from tests.service.test_service import DOC, TESTED, doc_blocks

    software, bench = doc_blocks(DOC.read_text(), TESTED)
    assert re.search(r"^SRC=\S+", software, re.M)
    assert "80-vcan0.netdev" in bench
    assert "enable --now rakectl-emulator rakectl" in bench
