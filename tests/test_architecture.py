"""The house rules, checked with the suite: the import contract, ruff, numpydoc docstrings.

The import contract (``[tool.importlinter]`` in pyproject.toml) fixes one import
direction — application → twin → parts → instrument core; ARCHITECTURE.md
explains it.  A test here also plants a wrong-way import in a copy of the tree
and checks that the contract catches it, so the contract cannot silently stop
biting.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent

#: Packages whose public API must carry numpydoc docstrings: the instrument core, the twin, the parts
#: — every module in them, found by walking the packages (a new module is covered without an edit);
#: the application (command line, reports, plots) and private modules (``_name``) are not.
DOCUMENTED_PACKAGES = ("scheimpflug", "sim", "scenes")
UNDOCUMENTED_PREFIXES = ("scheimpflug.app", "scheimpflug.__main__")


def documented_modules() -> list[str]:
    """Every public module of the documented packages, by walking them (no import needed)."""
    found = []
    for pkg in DOCUMENTED_PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join(parts)
            if any(p.startswith("_") for p in parts) or name.startswith(UNDOCUMENTED_PREFIXES):
                continue
            found.append(name)
    return found


#: numpydoc checks that must pass (numpydoc.validate.ERROR_MSGS): a docstring exists, every
#: parameter is documented with a type and a description and no unknown one is, a function that
#: returns or yields something says what.
NUMPYDOC_CHECKS = {"GL08", "PR01", "PR02", "PR04", "PR07", "RT01", "RT03", "YD01"}


def _tool(name: str) -> str:
    exe = BIN / name
    if not exe.exists():
        pytest.fail(f"{name} is not installed in this environment (pip install -e '.[test]')")
    return str(exe)


def test_import_contract_is_kept():
    res = subprocess.run([_tool("lint-imports")], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]


@pytest.mark.parametrize("module, code, chain", [
    ("scheimpflug/stripe.py", "import sim.render", "scheimpflug.stripe -> sim.render"),
    # a core module nobody has listed anywhere is covered too (the contract is a wildcard)
    ("scheimpflug/new_core_module.py", "import mitsuba", "scheimpflug.new_core_module -> mitsuba"),
    ("scheimpflug/model/new_model.py", "import scheimpflug.stripe",
     "scheimpflug.model.new_model -> scheimpflug.stripe"),
])
def test_import_contract_catches_a_wrong_way_import(tmp_path, module, code, chain):
    """A wrong-way import, in a module old or new, must break the contract (the test of the test)."""
    for pkg in ("scheimpflug", "sim", "scenes"):
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    target = tmp_path / module
    before = target.read_text() if target.exists() else '"""A module."""\n'
    target.write_text(before + f"\n\ndef _wrong_way():\n    {code}  # noqa\n")
    env = {"PYTHONPATH": str(tmp_path), "PATH": str(BIN)}
    res = subprocess.run([_tool("lint-imports")], cwd=tmp_path, capture_output=True, text=True, env=env)
    assert res.returncode != 0
    assert chain in res.stdout


#: Why a test may compare floats bit for bit (``# exact: <reason>`` on the line or the line above):
#: the project promises bit-identity only on one machine, for the same seed and configuration.
EXACT_REASONS = {
    "same run": "the same seed and configuration, twice on this machine",
    "threads": "another thread, worker or Dask-worker count on this machine (ordered accumulation)",
    "resume": "a resumed or repaired run against an uninterrupted one, on this machine",
    "copy": "the same values stored, read back, converted or looked up, with no arithmetic between",
    "integers": "integer, boolean, id or whole-pixel values",
}
_EXACT = re.compile(r"(?<!not )(?<!not np\.)(np\.testing\.assert_array_equal\(|np\.array_equal\(|array_equal\("
                    r"|\.tobytes\(\) ==|\.read_bytes\(\) ==|\b_(digest|hashes|numbers|files)\([^)]*\) ==)")


def _exact_comparisons_without_reason() -> list[str]:
    bad = []
    for path in sorted((ROOT / "tests").glob("test_*.py")):
        if path.name == Path(__file__).name:      # this file quotes the patterns it looks for
            continue
        lines = path.read_text().splitlines()
        for i, line in enumerate(lines):
            m = _EXACT.search(line)
            if not m or line[:m.start()].rstrip().endswith("not"):
                continue
            tagged = re.compile(r"# exact: (" + "|".join(EXACT_REASONS) + r")\b")
            if not (tagged.search(line) or (i and tagged.search(lines[i - 1]))):
                bad.append(f"{path.name}:{i + 1}: {line.strip()[:90]}")
    return bad


def test_no_exact_float_comparison_without_its_reason():
    """Every bit-for-bit comparison in the suite says why it may be exact (issue 25): floats of
    different code paths, configurations or machines are compared with a tolerance instead."""
    bad = _exact_comparisons_without_reason()
    assert not bad, ("exact comparisons without '# exact: <reason>' (" + ", ".join(EXACT_REASONS) + "):\n"
                     + "\n".join(bad))


def test_the_exact_comparison_lint_bites(tmp_path, monkeypatch):
    """The lint finds an untagged comparison and accepts a tagged one (the test of the test)."""
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_x.py").write_text(
        "assert np.array_equal(a, b)\n"
        "assert np.array_equal(a, b)  # exact: same run\n"
        "assert not np.array_equal(a, c)\n"
        "# exact: copy\nnp.testing.assert_array_equal(x, y)\n"
        "assert _digest(p) == _digest(q)  # exact: because\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert [b.split(":")[1] for b in _exact_comparisons_without_reason()] == ["1", "6"]


def test_ruff_is_clean():
    res = subprocess.run([_tool("ruff"), "check", "--no-cache", "."], cwd=ROOT, capture_output=True,
                         text=True)
    assert res.returncode == 0, res.stdout[-4000:]


def _public_objects():
    for modname in documented_modules():
        mod = importlib.import_module(modname)
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name, None)       # a package's __all__ may name its submodules
            if getattr(obj, "__module__", None) != modname:
                continue
            if inspect.isfunction(obj):
                yield f"{modname}.{name}", obj
            elif inspect.isclass(obj):
                yield f"{modname}.{name}", obj
                for attr, member in vars(obj).items():
                    if attr.startswith("_") or not inspect.isfunction(member):
                        continue
                    yield f"{modname}.{name}.{attr}", member


def _raises_directly(fn) -> bool:
    """Whether the function's own body (not nested functions) has a ``raise`` with an exception."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    except (OSError, TypeError, SyntaxError):
        return False
    body = tree.body[0]

    def walk(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
                continue
            if isinstance(child, ast.Raise) and child.exc is not None:
                yield child
            yield from walk(child)

    return any(True for _ in walk(body))


def test_public_api_has_numpydoc_docstrings():
    from numpydoc.validate import validate

    problems = []
    for path, obj in _public_objects():
        errors = [f"{code} {msg}" for code, msg in validate(path)["errors"] if code in NUMPYDOC_CHECKS]
        doc = inspect.getdoc(obj) or ""
        if inspect.isfunction(obj) and _raises_directly(obj) and "Raises\n------" not in doc:
            errors.append("RA01 raises an exception but has no Raises section")
        problems += [f"{path}: {e}" for e in errors]
    assert not problems, f"{len(problems)} docstring problems:\n" + "\n".join(problems)


def test_sim_package_exports_resolve_without_importing_mitsuba():
    """``import sim`` stays cheap (no Mitsuba/Dr.Jit); every name of ``sim.__all__`` resolves."""
    code = textwrap.dedent("""
        import importlib
        import sys

        import sim

        assert not {"mitsuba", "drjit"} & set(sys.modules), "import sim imported mitsuba/drjit"
        assert sim.__all__ == sorted(set(sim.__all__))
        for name in sim.__all__:
            home = importlib.import_module(sim._EXPORTS[name])
            assert getattr(sim, name) is getattr(home, name), name
        assert not {"mitsuba", "drjit"} & set(sys.modules), "sim.__all__ imported mitsuba/drjit"
        print("resolved", len(sim.__all__))
    """)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert res.stdout.startswith("resolved ")
