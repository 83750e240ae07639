"""The application: the ``scheimpflug`` command line, the demo, reports, plots, progress.

The only layer that imports the twin (:mod:`sim`) and the parts
(:mod:`scenes`); see ARCHITECTURE.md.  Each subcommand lives in
:mod:`scheimpflug.app.commands` as ``<name>.py`` with ``add_parser(subparsers)``.
"""
