"""The reference pages generated from the code: the command line and the rig keys.

One source of truth each: the command line reference is read from the argparse
parsers (:func:`scheimpflug.app.cli.build_parser`), the rig-key reference from the
rig's dataclasses (their fields and defaults), their numpydoc docstrings (the
description and the unit in brackets) and :data:`scheimpflug.model.rig.KEY_RANGES`
(the range).  The functions here are pure Python (no Sphinx), so
``tests/test_docs_reference.py`` checks them without a docs build; :func:`setup`
registers the two directives that put their text into the pages:

``.. scheimpflug-cli::``
    every subcommand with its usage, description and a table of its options;
``.. scheimpflug-rig-keys::``
    one table per rig table: key, unit, default, range, the paper preset's value
    and the description.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CliCommand", "CliOption", "RigKey", "cli_commands", "cli_rst", "escape_bars", "rig_keys", "rig_keys_rst",
           "run_command", "check_links", "setup"]

PROG = "scheimpflug"
_ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------ command line


@dataclass(frozen=True)
class CliOption:
    """One argument of a subcommand, as its parser declares it."""

    names: tuple[str, ...]       # ("--out",) or ("spec",) for a positional
    metavar: str                 # what follows the option ("" for a flag)
    help: str                    # the parser's help text ("" when it has none)
    default: str                 # the default shown ("" when none worth showing)
    choices: tuple[str, ...]
    required: bool
    exclusive_with: tuple[str, ...]  # options of the same mutually exclusive group

    @property
    def label(self) -> str:
        """The option as a user types it: ``--out DIR``, ``SPEC.toml``."""
        if not self.names[0].startswith("-"):
            return self.metavar or self.names[0]
        names = ", ".join(self.names)
        return f"{names} {self.metavar}" if self.metavar else names


@dataclass(frozen=True)
class CliCommand:
    """One (sub)command: ``("dataset", "make")`` with its parser's texts and options."""

    path: tuple[str, ...]
    help: str
    description: str
    usage: str
    options: tuple[CliOption, ...]
    subcommands: tuple[str, ...]

    @property
    def name(self) -> str:
        """``scheimpflug dataset make``."""
        return " ".join((PROG, *self.path))


def _metavar(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.metavar is not None:
        return action.metavar if isinstance(action.metavar, str) else " ".join(action.metavar)
    if action.choices is not None:
        return "{" + ",".join(map(str, action.choices)) + "}"
    base = action.dest.upper() if action.option_strings else action.dest
    if action.nargs in ("+", "*"):
        return f"{base} ..."
    if isinstance(action.nargs, int) and action.nargs > 1:
        return " ".join([base] * action.nargs)
    return base


def _default(action: argparse.Action) -> str:
    d = action.default
    if action.nargs == 0 or d is None or d is argparse.SUPPRESS or d == [] or d is False:
        return ""
    return str(d)


def _exclusive(parser: argparse.ArgumentParser) -> dict[int, tuple[str, ...]]:
    out: dict[int, tuple[str, ...]] = {}
    for group in parser._mutually_exclusive_groups:
        names = tuple(a.option_strings[0] if a.option_strings else a.dest for a in group._group_actions)
        for a in group._group_actions:
            out[id(a)] = tuple(n for n in names if n not in a.option_strings and n != a.dest)
    return out


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...], help_text: str) -> Iterator[CliCommand]:
    options, subs = [], {}
    exclusive = _exclusive(parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {c.dest: c.help or "" for c in action._choices_actions}
            subs = {name: (sp, helps.get(name, "")) for name, sp in action.choices.items()}
        elif not isinstance(action, argparse._HelpAction):
            options.append(CliOption(
                names=tuple(action.option_strings) or (action.dest,), metavar=_metavar(action),
                help="" if action.help in (None, argparse.SUPPRESS) else " ".join(str(action.help).split()),
                default=_default(action), choices=tuple(map(str, action.choices or ())),
                required=bool(action.required), exclusive_with=exclusive.get(id(action), ())))
    usage = " ".join(parser.format_usage().replace("usage:", "", 1).split())
    yield CliCommand(path=path, help=help_text, description=" ".join((parser.description or "").split()),
                     usage=usage, options=tuple(options), subcommands=tuple(subs))
    for name, (sp, sub_help) in subs.items():
        yield from _walk(sp, (*path, name), sub_help)


def cli_commands(parser: argparse.ArgumentParser | None = None) -> list[CliCommand]:
    """Every command of the console script, the top level first, then depth first.

    Parameters
    ----------
    parser : argparse.ArgumentParser, optional
        Default :func:`scheimpflug.app.cli.build_parser` ().

    Returns
    -------
    list of CliCommand
        ``scheimpflug`` itself, each subcommand and each sub-subcommand
        (``dataset make``), in the parser's order.
    """
    if parser is None:
        from scheimpflug.app.cli import build_parser

        parser = build_parser()
    return list(_walk(parser, (), parser.description or ""))


def _esc(text: str) -> str:
    """Text safe inside reStructuredText (no markup is meant)."""
    return re.sub(r"([\\`*_|])", r"\\\1", text)


def _anchor(path: tuple[str, ...]) -> str:
    return "cli-" + "-".join((PROG, *path))


def cli_rst(commands: list[CliCommand] | None = None) -> str:
    """The command-line reference as reStructuredText: one section per command.

    Parameters
    ----------
    commands : list of CliCommand, optional
        Default :func:`cli_commands` ().

    Returns
    -------
    str
        Sections titled ``scheimpflug COMMAND`` with the usage, the description and a
        table of the options (value, default, choices, what it does); labels
        ``cli-scheimpflug-COMMAND`` for cross-references.
    """
    commands = cli_commands() if commands is None else commands
    lines: list[str] = []
    for cmd in commands:
        if not cmd.path:
            continue
        title = f"``{cmd.name}``"
        mark = "=" if len(cmd.path) == 1 else "-"
        lines += [f".. _{_anchor(cmd.path)}:", "", title, mark * len(title), ""]
        if cmd.help:
            lines += [_esc(cmd.help[0].upper() + cmd.help[1:]) + ".", ""]
        usage = textwrap.wrap(cmd.usage, 100, subsequent_indent=" " * (len(cmd.name) + 1), break_on_hyphens=False,
                              break_long_words=False)
        lines += [".. code-block:: text", "", *("   " + u for u in usage), ""]
        if cmd.description:
            lines += [_esc(cmd.description), ""]
        if cmd.subcommands:
            lines += ["Subcommands (below): " + ", ".join(f"``{s}``" for s in cmd.subcommands) + ".", ""]
        opts = [o for o in cmd.options if o.names != ("--debug",) or not cmd.path]
        if opts:
            lines += [".. list-table::", "   :header-rows: 1", "   :widths: 30 12 58", "   :class: cli-options", "",
                      "   * - argument", "     - default", "     - what it does"]
            for o in opts:
                extra = []
                if o.choices and not o.label.startswith("{"):
                    extra.append("one of " + ", ".join(f"``{c}``" for c in o.choices))
                if o.required and o.names[0].startswith("-"):
                    extra.append("required")
                if o.exclusive_with:
                    extra.append("not with " + ", ".join(f"``{n}``" for n in o.exclusive_with))
                text = _esc(o.help) + (f" ({'; '.join(extra)})" if extra else "")
                default = f"``{o.default}``" if o.default else ""
                lines += [f"   * - ``{o.label}``", f"     - {default}", f"     - {text}"]
            lines.append("")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ rig keys

_TABLE_NAMES = ("lens", "laser", "sensor", "stage", "environment", "twin")
_NUMBER = re.compile(r"^\s*[-+]?(\d|\.\d|inf)")


@dataclass(frozen=True)
class RigKey:
    """One key of the rig file with everything the reference shows about it."""

    table: str
    key: str
    type: str            # "float", "int", "bool", "str"
    unit: str            # from the docstring's brackets; "" when it has none
    default: str         # the dataclass default ("derived" when the rule of model/plan.py sets it)
    range: str           # KEY_RANGES
    paper: str           # the paper preset's value ("" when the preset leaves it out)
    description: str     # the docstring's text
    group: str           # the error-model source it belongs to, "derived", or ""

    @property
    def name(self) -> str:
        """``table.key``."""
        return f"{self.table}.{self.key}"


def _units(desc: str, n_names: int, index: int) -> str:
    found = [m.strip() for m in re.findall(r"\[([^\[\]]*)\]", desc)
             if not _NUMBER.match(m) and m.strip() not in _TABLE_NAMES]
    if not found:
        return ""
    parts = [p.strip() for p in found[0].split(",")]
    if n_names > 1 and len(parts) == n_names:
        return parts[index]
    return found[0]


def _rst_text(desc: str) -> str:
    """A numpydoc description as one line of reST (roles kept, stray markup escaped)."""
    return " ".join(desc.split()).replace("|", "\\|")


def _show(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def _field_type(f: dataclasses.Field) -> str:
    text = str(f.type)
    for name in ("bool", "int", "float", "str"):
        if re.search(rf"\b{name}\b", text):
            return name
    return text


def rig_keys() -> list[RigKey]:
    """Every key of the rig file, table by table in the file's order.

    Returns
    -------
    list of RigKey
        From the dataclasses of :mod:`scheimpflug.model.rig` (field, type, default),
        their docstrings (description, unit) and ``KEY_RANGES`` (range); the paper
        value from ``presets/paper.toml``; the group from ``ERROR_MODELS``,
        ``ERROR_MODEL_SHAPES``, ``TWIN_EFFECTS`` and ``DERIVED_KEYS``.  A key whose
        docstring has no entry gets an empty description (the test fails on it).
    """
    from numpydoc.docscrape import NumpyDocString

    from scheimpflug.model import rig

    groups = {k: f"error model: {g}" for g, keys in rig.ERROR_MODELS.items() for k in keys}
    groups.update({k: f"shapes the error model: {g}" for g, keys in rig.ERROR_MODEL_SHAPES.items() for k in keys})
    groups.update({k: f"twin effect: {g}" for g, keys in rig.TWIN_EFFECTS.items() for k in keys})
    groups.update({k: "derived when left out" for k in rig.DERIVED_KEYS})
    paper = rig.preset_tables("paper")
    out: list[RigKey] = []
    for table, cls in rig._TABLES.items():
        params = {}
        for p in NumpyDocString(cls.__doc__ or "")["Parameters"]:
            names = [n.strip() for n in p.name.split(",")]
            for i, n in enumerate(names):
                params[n] = (p, len(names), i)
        for f in dataclasses.fields(cls):
            p, n, i = params.get(f.name, (None, 1, 0))
            desc = " ".join(p.desc) if p is not None else ""
            name = f"{table}.{f.name}"
            default = "derived" if f.default is None and name in rig.DERIVED_KEYS else _show(f.default)
            out.append(RigKey(table=table, key=f.name, type=_field_type(f), unit=_units(desc, n, i),
                              default=default, range=rig.KEY_RANGES.get(table, {}).get(f.name, ""),
                              paper=_show(paper[table][f.name]) if f.name in paper.get(table, {}) else "",
                              description=desc, group=groups.get(name, "")))
    return out


def rig_keys_rst(keys: list[RigKey] | None = None) -> str:
    """The rig-key reference as reStructuredText: one table per rig table.

    Parameters
    ----------
    keys : list of RigKey, optional
        Default :func:`rig_keys` ().

    Returns
    -------
    str
        A section per table (``[lens]`` …) with a list table: key, unit, default,
        range, the paper preset's value, and the description; labels
        ``rig-TABLE-KEY`` for cross-references.
    """
    keys = rig_keys() if keys is None else keys
    lines: list[str] = []
    for table in dict.fromkeys(k.table for k in keys):
        title = f"``[{table}]``"
        lines += [f".. _rig-table-{table}:", "", title, "-" * len(title), "",
                  ".. list-table::", "   :header-rows: 1", "   :widths: 18 7 9 13 9 44", "   :class: rig-keys", "",
                  "   * - key", "     - unit", "     - default", "     - range", "     - paper", "     - meaning"]
        for k in (k for k in keys if k.table == table):
            group = f" *({k.group})*" if k.group else ""
            lines += [f"   * - .. _rig-{table}-{k.key}:", "", f"       ``{k.key}``",
                      f"     - {'–' if k.unit in ('', '-') else _esc(k.unit)}", f"     - ``{k.default}``",
                      f"     - ``{k.range}``", f"     - {'``' + k.paper + '``' if k.paper else ''}",
                      f"     - {_rst_text(k.description)}{group}"]
        lines.append("")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ docstrings as reST

_LITERAL = re.compile(r"(``.+?``|`[^`]+`)")


def escape_bars(line: str) -> str:
    r"""A docstring line with its ``|x|`` (absolute value, norm) notation escaped for reST.

    The docstrings write |x| for a magnitude, as plain text does; reST would read it
    as a substitution.  Bars inside literals and interpreted text are left alone, and
    so are the lines of a line block (``| text``) and of a grid table (``+---+``).

    Parameters
    ----------
    line : str
        One line of a docstring.

    Returns
    -------
    str
        The line with every other ``|`` written ``\|``.
    """
    head = line.lstrip()
    if "|" not in line or head in ("|", "") or head.startswith(("| ", "+-", "+=")):
        return line
    parts = _LITERAL.split(line)
    return "".join(p if i % 2 else p.replace("\\|", "|").replace("|", "\\|") for i, p in enumerate(parts))


def _process_docstring(app, what, name, obj, options, lines):  # pragma: no cover - Sphinx event
    lines[:] = [escape_bars(line) for line in lines]


# ------------------------------------------------------------------ commands run at build time


def run_command(argv: list[str]) -> tuple[int, str]:
    """Run ``scheimpflug ARGV`` in this process and return its exit status and output.

    Parameters
    ----------
    argv : list of str
        The arguments after ``scheimpflug`` (e.g. ``["design", "--preset", "paper"]``).

    Returns
    -------
    status : int
        The command's exit status.
    text : str
        What it printed on stdout, then what it printed on stderr.
    """
    import contextlib
    import io

    from scheimpflug.app.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(list(argv))
    return int(status), out.getvalue() + err.getvalue()


# ------------------------------------------------------------------ internal links of the built site


def check_links(html_dir: str | Path) -> list[str]:
    """Every internal link and image of a built HTML site that points nowhere.

    Parameters
    ----------
    html_dir : path
        The HTML output folder (``docs/_build/html``).

    Returns
    -------
    list of str
        ``page: href`` for each link to a missing file or to an anchor the target
        page does not have (external ``http(s)``, ``mailto`` and ``data`` links are
        not followed); empty when all resolve.
    """
    from html.parser import HTMLParser
    from urllib.parse import unquote, urlsplit

    class _Page(HTMLParser):
        def __init__(self):
            super().__init__(convert_charrefs=True)
            self.ids, self.links = set(), []

        def handle_starttag(self, tag, attrs):
            a = dict(attrs)
            for key in ("id", "name"):
                if a.get(key):
                    self.ids.add(a[key])
            for key in ("href", "src"):
                if a.get(key) and not (tag == "link" and key == "href" and a.get("rel") == "preconnect"):
                    self.links.append(a[key])

    root = Path(html_dir)
    pages: dict[Path, _Page] = {}
    for path in sorted(root.rglob("*.html")):
        if path.relative_to(root).parts[0] in ("_static", "_sources"):    # the theme's templates, sources
            continue
        page = _Page()
        page.feed(path.read_text(encoding="utf-8", errors="replace"))
        pages[path.resolve()] = page
    bad = []
    for path, page in pages.items():
        for href in page.links:
            parts = urlsplit(href)
            if parts.scheme or parts.netloc or href.startswith(("mailto:", "data:", "javascript:")):
                continue
            target = (path.parent / unquote(parts.path)).resolve() if parts.path else path
            if parts.path.endswith("/") or target.is_dir():
                target = target / "index.html"
            if not target.exists():
                bad.append(f"{path.relative_to(root.resolve())}: {href} (no such file)")
            elif parts.fragment and target.suffix == ".html" and target in pages \
                    and unquote(parts.fragment) not in pages[target].ids:
                bad.append(f"{path.relative_to(root.resolve())}: {href} (no such anchor)")
    return bad


def _main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] != "check-links":
        print("usage: scheimpflug_docs.py check-links HTML_DIR", file=sys.stderr)
        return 2
    bad = check_links(argv[1])
    for line in bad:
        print(f"broken internal link: {line}", file=sys.stderr)
    n = sum(1 for _ in Path(argv[1]).rglob("*.html"))
    print(f"check-links: {n} pages, {len(bad)} broken internal links", file=sys.stderr)
    return 1 if bad else 0


# ------------------------------------------------------------------ Sphinx


def setup(app):  # pragma: no cover - exercised by the docs build
    """Register the ``scheimpflug-cli`` and ``scheimpflug-rig-keys`` directives and the docstring filter."""
    from docutils import nodes
    from docutils.statemachine import StringList
    from sphinx.util.docutils import SphinxDirective
    from sphinx.util.nodes import nested_parse_with_titles

    class _Generated(SphinxDirective):
        has_content = False
        make = staticmethod(lambda: "")

        def run(self):
            node = nodes.section()
            node.document = self.state.document
            text = self.make()
            source = f"<generated by {type(self).__name__}>"
            nested_parse_with_titles(self.state, StringList(text.splitlines(), source=source), node)
            for dep in ("scheimpflug/app/cli.py", "scheimpflug/model/tables.py", "scheimpflug/model/keys.py"):
                self.env.note_dependency(str(_ROOT / dep))
            return node.children

    class CliDirective(_Generated):
        make = staticmethod(cli_rst)

    class RigKeysDirective(_Generated):
        make = staticmethod(rig_keys_rst)

    class RunDirective(SphinxDirective):
        """``.. scheimpflug-run:: design --preset paper``: the command and its output, run now."""

        required_arguments = 1
        final_argument_whitespace = True

        def run(self):
            import shlex

            argv = shlex.split(self.arguments[0])
            status, text = run_command(argv)
            if status != 0:
                raise self.error(f"scheimpflug {self.arguments[0]} exited with status {status}: {text[-500:]}")
            block = nodes.literal_block(text="$ scheimpflug " + self.arguments[0] + "\n" + text.rstrip("\n"))
            block["language"] = "text"
            return [block]

    app.add_directive("scheimpflug-cli", CliDirective)
    app.add_directive("scheimpflug-run", RunDirective)
    app.add_directive("scheimpflug-rig-keys", RigKeysDirective)
    app.connect("autodoc-process-docstring", _process_docstring, priority=600)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
