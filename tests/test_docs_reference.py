"""The documentation's reference against the code, without a Sphinx build.

The command-line and rig-key pages are generated from the code
(``docs/_ext/scheimpflug_docs.py``); these tests fail when the code gains
something the pages could not document — an option without help text, a rig key
without a description, unit or range — or when a hand-written contract page
falls behind: a subcommand missing from the interface contract, a JSON field of
the contract or of ``design --json`` missing from the JSON reference, a file
citing a document that is not in the repository.  They also run the docstring
examples of the instrument core (doctest).
"""

from __future__ import annotations

import doctest
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import scheimpflug_docs as ref  # noqa: E402


def _norm(text: str) -> str:
    return " ".join(text.split())


@pytest.fixture(scope="module")
def commands():
    return ref.cli_commands()


@pytest.fixture(scope="module")
def rig_keys():
    return ref.rig_keys()


# ------------------------------------------------------------------ command line


def test_every_command_and_option_has_help_text(commands):
    missing = [f"{c.name}: {'/'.join(o.names)}" for c in commands for o in c.options if not o.help.strip()]
    missing += [f"{c.name}: the command itself" for c in commands if c.path and not c.help.strip()]
    assert not missing, "options without help text (the CLI reference would show nothing):\n" + "\n".join(missing)


def test_the_cli_reference_shows_every_command_and_option(commands):
    page = ref.cli_rst(commands)
    leaves = [c for c in commands if c.path]
    assert {"design", "render", "calibrate", "reconstruct", "evaluate", "dataset", "study"} <= {
        c.path[0] for c in leaves}
    for c in leaves:
        assert f"``{c.name}``" in page and f".. _cli-{'-'.join(('scheimpflug', *c.path))}:" in page, c.name
        block = page.split(f"``{c.name}``", 1)[1].split("\n.. _cli-", 1)[0]
        for o in c.options:
            assert f"``{o.label}``" in block and ref._esc(o.help) in block, (c.name, o.names)


def test_every_subcommand_is_in_the_interface_contract(commands):
    contract = _norm((DOCS / "reference" / "interface.md").read_text())
    for c in commands:
        if c.path and not c.subcommands:
            assert c.name + " " in contract, f"{c.name} is not in docs/reference/interface.md"


# ------------------------------------------------------------------ rig keys


def test_every_rig_key_has_a_description_a_unit_and_a_range(rig_keys):
    from scheimpflug.model.rig import KEY_RANGES

    bad = []
    for k in rig_keys:
        if not k.description:
            bad.append(f"{k.name}: no entry in its dataclass docstring")
        if not k.range:
            bad.append(f"{k.name}: no range in KEY_RANGES")
        if k.type in ("int", "float") and not k.unit:
            bad.append(f"{k.name}: no unit in brackets in its docstring ([-] for none)")
    names = {k.name for k in rig_keys}
    bad += [f"{t}.{key}: in KEY_RANGES but not a rig key" for t, keys in KEY_RANGES.items() for key in keys
            if f"{t}.{key}" not in names]
    assert not bad, "\n".join(bad)
    assert len(rig_keys) >= 70


def test_the_rig_key_reference_shows_every_key(rig_keys):
    page = ref.rig_keys_rst(rig_keys)
    for k in rig_keys:
        row = page.split(f".. _rig-{k.table}-{k.key}:", 1)[1].split("   * - ", 1)[0]
        assert f"``{k.key}``" in row and f"``{k.range}``" in row and f"``{k.default}``" in row, k.name
    focal = next(k for k in rig_keys if k.name == "lens.focal_length_mm")
    assert (focal.unit, focal.default, focal.range, focal.paper) == ("mm", "55.0", "[0.5, 5000]", "55.0")
    d0 = next(k for k in rig_keys if k.name == "stage.d0_mm")
    assert (d0.default, d0.paper, d0.group) == ("derived", "-466.0", "derived when left out")
    offsets = {k.key: k.unit for k in rig_keys if k.key.startswith("offset_")}
    assert offsets == {"offset_u_px": "px", "offset_v_px": "px", "offset_normal_um": "µm"}


# ------------------------------------------------------------------ JSON fields


def _contract_json_fields() -> dict[str, list[str]]:
    text = (DOCS / "reference" / "interface.md").read_text()
    section = text.split("## JSON fields that must exist", 1)[1].split("\n## ", 1)[0]
    fields = {}
    for item in re.split(r"\n- ", "\n" + section.strip()):
        if ":" not in item:
            continue
        command, rest = item.split(":", 1)
        fields[command.strip()] = re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", rest)
    return fields


def test_every_contract_json_field_is_in_the_json_reference():
    fields = _contract_json_fields()
    assert {"design", "calibrate", "axis", "evaluate", "acceptance"} <= set(fields)
    page = (DOCS / "reference" / "json.md").read_text()
    missing = [f"{c}: {f}" for c, names in fields.items() for f in names if f"`{f}`" not in page]
    assert not missing, "JSON fields of the contract missing from docs/reference/json.md: " + ", ".join(missing)


def test_every_field_design_prints_is_in_the_json_reference():
    status, text = ref.run_command(["design", "--preset", "paper", "--json"])
    assert status == 0
    import json

    out = json.loads(text[text.index("{"):])
    names = set(out) | set(out["calibration_plan"]) | set(out["rotary_plan"]) | set(out["stage"])
    page = (DOCS / "reference" / "json.md").read_text() + (DOCS / "reference" / "rig-keys.md").read_text()
    missing = sorted(n for n in names if f"`{n}`" not in page and n not in ref.rig_keys_rst())
    assert not missing, "design --json fields missing from docs/reference/json.md: " + ", ".join(missing)


# ------------------------------------------------------------------ citations and doctests

#: A document cited by a name the repository does not have (the team's notes outside it); data read from
#: outside the tree (``../shared/realdata``) is not a document and not cited here.
_CITATION = re.compile(r"(?<![\w/.-])(?:INTERFACE|DESIGN)\.md\b|\.\./shared/\S*\.md")


def test_no_file_cites_a_document_outside_the_repository():
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    this = Path(__file__).relative_to(ROOT).as_posix()
    found = []
    for name in files:
        path = ROOT / name
        if name == this or path.suffix not in (".py", ".md", ".rst", ".toml", ".txt", ".sh", "") or not path.is_file():
            continue
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if _CITATION.search(line):
                found.append(f"{name}:{n}: {line.strip()[:100]}")
    assert not found, ("citations of INTERFACE.md / DESIGN.md / ../shared (now docs/reference/interface.md and "
                       "docs/explanation/design-notes.md):\n" + "\n".join(found))


def _core_modules() -> list[str]:
    names = []
    for path in sorted((ROOT / "scheimpflug").rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if "app" in parts or any(p.startswith("_") for p in parts):
            continue
        names.append(".".join(parts))
    return names


def test_the_docstring_examples_of_the_core_run():
    attempted = failed = 0
    for name in _core_modules():
        result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS, verbose=False)
        attempted += result.attempted
        failed += result.failed
    assert failed == 0
    assert attempted >= 8      # at least those of scheimpflug.model.hinge and .design
