"""The documentation site (Sphinx + MyST + breathe). Build it with scripts/docs, which builds
skyloop first: the reference pages are generated from the program itself (docs/_generate.py) and
the Python reference imports the built module."""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
BUILD = os.environ.get("SKYLOOP_BUILD_DIR", os.path.join(ROOT, "build"))
sys.path.insert(0, os.path.join(BUILD, "python"))
sys.path.insert(0, HERE)

project = "skyloop"
copyright = "the skyloop authors"
author = "the skyloop authors"
with open(os.path.join(ROOT, "VERSION")) as f:  # one version: CMake, the package and the docs read it
    release = version = f.read().strip()

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "breathe"]
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3
source_suffix = {".md": "markdown"}
exclude_patterns = ["_build", "README.md"]
html_theme = "alabaster"
html_title = f"skyloop {release}"
html_theme_options = {"description": "multi-UAV beamforming and trajectories", "fixed_sidebar": True,
                      "page_width": "1100px", "sidebar_width": "240px"}
html_sidebars = {"**": ["about.html", "navigation.html", "relations.html", "searchbox.html"]}
autodoc_member_order = "bysource"
autodoc_inherit_docstrings = False  # the adapters' methods keep their own words, not Gymnasium's
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}

# The public C++ headers: one doxygen project per directory of include/skyloop (its XML made by
# _generate.py under the build directory).
_areas = sorted(d for d in os.listdir(os.path.join(ROOT, "include", "skyloop")) if not d.startswith("."))
breathe_projects = {f"skyloop-{a}": os.path.join(BUILD, "docs", "doxygen", a, "xml") for a in _areas}
breathe_default_project = "skyloop-core"
breathe_default_members = ("members",)
# Each header's section opens `namespace skyloop`, which Sphinx's C++ domain counts as one more
# declaration of the namespace per header; the C++ domain is used only by the generated header
# pages, where nothing else is declared twice (one section per header).
suppress_warnings = ["duplicate_declaration.cpp"]


def _generate(app):
    import _generate
    _generate.main(BUILD)


def setup(app):
    app.connect("builder-inited", _generate)
