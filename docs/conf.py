"""Sphinx configuration of the scheimpflug documentation (``bash run.sh docs``).

Offline by design: the build needs nothing but the project's ``docs`` extra.  Two
things would otherwise reach the network and are handled here:

* intersphinx (links to numpy, scipy, trimesh, Mitsuba, Python): each inventory
  is probed first (2 s) and used only when it answers, so an offline build has no
  intersphinx warning.  ``SCHEIMPFLUG_DOCS_INTERSPHINX=0`` turns it off, ``=1``
  uses every inventory without probing (a failure is then a warning).
* MathJax: served from the build itself (``_static/mathjax/tex-svg.js``, copied
  from the ``django-static-mathjax`` wheel, which is MathJax 3.2 with no
  dependencies), so the equations render without a CDN.

``SCHEIMPFLUG_DOCS_GALLERY=0`` skips running the gallery examples (their pages
then show the code without figures); CI runs them.
"""

from __future__ import annotations

import os
import shutil
import sys
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(ROOT))

os.environ.setdefault("MPLBACKEND", "Agg")

import scheimpflug  # noqa: E402

project = "scheimpflug"
author = "the scheimpflug developers"
copyright = "2026, the scheimpflug developers"
release = version = scheimpflug.__version__

extensions = [
    "myst_parser",
    "numpydoc",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "sphinx_gallery.gen_gallery",
    "scheimpflug_docs",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "README.next.md", "**/README.md", "auto_examples/*.ipynb",
                    "auto_examples/*.py", "auto_examples/*.zip", "auto_examples/*.md5",
                    "auto_examples/*.json", "sg_execution_times.rst"]
templates_path = ["_templates"]
nitpicky = False
smartquotes = False                   # "--near-mm" stays two hyphens, not an en dash
suppress_warnings = ["config.cache"]   # sphinx-gallery's callables in the config cannot be pickled

# ------------------------------------------------------------------ MyST
myst_enable_extensions = ["amsmath", "dollarmath", "colon_fence", "deflist", "attrs_inline"]
myst_heading_anchors = 3
myst_dmath_double_inline = True

# ------------------------------------------------------------------ API reference
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "none"            # the numpydoc docstrings carry the types and units


def _shared_exports() -> dict:
    """Per module, the names of its ``__all__`` that another page describes.

    A subpackage leaves the names its top-level package exports too to the top-level page; a
    plain module leaves the names it only re-exports (a moved module's shim, such as
    ``scheimpflug.sheet_model``) to the module that defines them.  Two pages of one object
    would both claim its canonical name (Sphinx's duplicate-description warning, raised or not
    depending on how a parallel build splits the pages).
    """
    import importlib
    import pkgutil

    out = {}
    for top in ("scheimpflug", "sim", "scenes"):
        pkg = importlib.import_module(top)
        curated = set(getattr(pkg, "__all__", []))
        for info in pkgutil.walk_packages(pkg.__path__, top + "."):
            mod = importlib.import_module(info.name)
            names = set(getattr(mod, "__all__", []))
            if info.ispkg:
                shared = curated & names
            else:
                shared = {n for n in names if getattr(getattr(mod, n, None), "__module__", info.name)
                          not in (None, info.name)}
            if shared:
                out[info.name] = sorted(shared)
    return out


autosummary_context = {"shared_exports": _shared_exports()}
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()   # tests/test_architecture.py validates the docstrings

# ------------------------------------------------------------------ math without a CDN


def _local_mathjax() -> str | None:
    try:
        import mathjax  # django-static-mathjax: MathJax 3 as package data
    except ImportError:
        return None
    src = Path(mathjax.__file__).parent / "static" / "mathjax" / "es5" / "tex-svg.js"
    if not src.is_file():
        return None
    dst = HERE / "_static" / "mathjax"
    dst.mkdir(parents=True, exist_ok=True)
    if not (dst / src.name).is_file() or (dst / src.name).stat().st_size != src.stat().st_size:
        shutil.copyfile(src, dst / src.name)
    return "mathjax/tex-svg.js"


_mathjax = _local_mathjax()
if _mathjax is not None:              # else Sphinx's default (a CDN): the docs extra is not installed
    mathjax_path = _mathjax
mathjax3_config = {"tex": {"tags": "none"}, "svg": {"fontCache": "global"}}

# ------------------------------------------------------------------ intersphinx, when reachable

_INVENTORIES = {
    "python": "https://docs.python.org/3",
    "numpy": "https://numpy.org/doc/stable",
    "scipy": "https://docs.scipy.org/doc/scipy",
    "trimesh": "https://trimesh.org",
    "mitsuba": "https://mitsuba.readthedocs.io/en/stable",
}


def _reachable(url: str) -> bool:
    try:
        req = urllib.request.Request(f"{url}/objects.inv", method="HEAD")
        with urllib.request.urlopen(req, timeout=2) as resp:
            return resp.status == 200
    except Exception:
        return False


def _intersphinx_mapping() -> dict:
    mode = os.environ.get("SCHEIMPFLUG_DOCS_INTERSPHINX", "auto").strip().lower()
    if mode in ("0", "off", "no", "false"):
        return {}
    if mode in ("1", "on", "yes", "true"):
        return {k: (v, None) for k, v in _INVENTORIES.items()}
    with ThreadPoolExecutor(len(_INVENTORIES)) as pool:
        ok = dict(zip(_INVENTORIES, pool.map(_reachable, _INVENTORIES.values())))
    return {k: (v, None) for k, v in _INVENTORIES.items() if ok[k]}


intersphinx_mapping = _intersphinx_mapping()
intersphinx_timeout = 5

# ------------------------------------------------------------------ gallery


def _reset_matplotlib(gallery_conf, fname):
    import matplotlib

    matplotlib.rcParams.update(matplotlib.rcParamsDefault)
    matplotlib.rcParams.update({"figure.dpi": 100, "savefig.dpi": 100, "font.size": 11})


sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "plot_gallery": os.environ.get("SCHEIMPFLUG_DOCS_GALLERY", "1") not in ("0", "false", "no"),
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "only_warn_on_example_error": False,
    "reset_modules": (_reset_matplotlib,),
    "matplotlib_animations": False,
    "image_srcset": [],
    "within_subsection_order": "FileNameSortKey",
    "show_memory": False,
    "capture_repr": (),
}

# ------------------------------------------------------------------ HTML
html_theme = "pydata_sphinx_theme"
html_title = "scheimpflug"
html_static_path = ["_static"]
html_css_files = ["scheimpflug.css"]
html_show_sourcelink = False
html_theme_options = {
    "navbar_align": "left",
    "show_toc_level": 2,
    "navigation_with_keys": False,
    "header_links_before_dropdown": 6,
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
    "check_switcher": False,
}
html_theme_options["secondary_sidebar_items"] = {"**": ["page-toc"], "reference/rig-keys": [], "reference/cli": []}
html_context = {"default_mode": "light"}
