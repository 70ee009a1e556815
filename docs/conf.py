"""Sphinx configuration of vistask's documentation site (``make docs``)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # the grasp env's modules import robosuite

project = "vistask"
author = "vistask developers"
copyright = "vistask developers"
extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "runs"]
html_theme = "furo"
html_title = "vistask"

autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_class_signature = "separated"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
myst_heading_anchors = 3
autodoc_inherit_docstrings = False  # gymnasium.Env.step and the like are not ours
