"""The README's promises: its configuration table and its commands are the real ones."""

from __future__ import annotations

import re
from pathlib import Path

from rakectl.api.schema import api_reference
from rakectl.cli.docs import configuration_reference

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _generated(name: str) -> str:
    match = re.search(rf"{name}:start.*?-->\n(.*?)\n<!-- {name}:end", README, re.S)
    assert match, f"README lacks the generated {name}"
    return match.group(1).strip()


def test_configuration_reference_is_generated_from_the_declarations() -> None:
    assert _generated("config-reference") == configuration_reference().strip(), (
        "README configuration table is stale: regenerate with `rakectl config-docs`"
    )


def test_api_reference_is_generated_from_the_command_table() -> None:
    assert _generated("api-reference") == api_reference().strip(), (
        "README API reference is stale: regenerate with `rakectl api-docs`"
    )


def test_ci_runs_exactly_the_readme_test_command() -> None:
    blocks = re.findall(r"```sh\n(.*?)\n```", README, re.S)
    assert len(blocks) >= 2
    test_command = blocks[1].strip()
    assert test_command in (ROOT / ".ci" / "run").read_text()
