"""Sphinx configuration of torchpark's documentation site: the guides in this folder (MyST
Markdown) and a page per public object, from the docstrings (autodoc, napoleon).

    pip install -e ".[docs]"
    sphinx-build -W --keep-going -n docs docs/_build/html   # warnings are errors, nitpicky

Nothing outside the package index is reached: no intersphinx inventories, so the names of
torch, torchrl, tensordict, numpy, Gymnasium and Stable-Baselines3 are not linked
(``nitpick_ignore_regex``), and every name of torchpark's must resolve.
"""

from __future__ import annotations

import inspect
import re

project = "torchpark"
author = "the torchpark developers"
copyright = "2026, the torchpark developers"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build"]
templates_path = ["_templates"]
html_theme = "furo"
html_title = "torchpark"

autosummary_generate = True
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
napoleon_google_docstring = True
napoleon_numpy_docstring = False

nitpicky = True
# Names from other libraries (no inventory is reached) and Python's own typing names.
nitpick_ignore_regex = [
    (r"py:.*", r"(torch|torchrl|tensordict|numpy|np|gymnasium|stable_baselines3|collections"
               r"|typing|pathlib|abc|PIL)(\..*)?"),
    # private bases and type variables, which the site does not document
    (r"py:.*", r"torchpark\..*\._\w+|torchpark\.sim\.records\.R|torchpark\.sim\.step\.RowsT"),
    (r"py:.*", r"(Tensor|TensorDict|TensorDictBase|TensorSpec|Composite|Bounded|Unbounded"
               r"|Binary|EnvBase|TransformedEnv|Transform|VecEnv|VecEnvIndices|Env|VectorEnv"
               r"|Generator|Callable|Sequence|Iterator|Any|NamedTuple|ndarray|Path|NestedKey"
               r"|mp\..*)"),
]
# The guides link to files beside docs/ (the README, research/): tests/test_docs.py checks that
# each resolves; the site does not hold them.
suppress_warnings = ["myst.xref_missing"]
myst_heading_anchors = 3


def resolve_short_name(app, env, node, contnode):
    """A cross-reference that names a torchpark object without its module (the docstrings'
    ``:class:`ParkingConfig```, as ``help()`` reads best) resolved to the one object of the
    site whose dotted name ends with it; None (a nitpicky warning) where none or several do."""
    target = node.get("reftarget", "").removeprefix("torchpark.")
    if node.get("refdomain") != "py" or not target:
        return None
    domain = env.get_domain("py")
    found = [name for name in domain.objects if name.endswith("." + target)]
    if len(found) != 1:
        return None
    node["reftarget"] = found[0]
    return domain.resolve_xref(env, node.get("refdoc"), app.builder, node["reftype"], found[0],
                               node, contnode)


ABSOLUTE = re.compile(r"(?<![`|\w])\|([^|`\n]+)\|(?![`|\w])")


def literal_absolute_values(app, what, name, obj, options, lines):
    """The docstrings write absolute values as in mathematics, ``|dx|``, which reST would read
    as a substitution: shown as literals instead."""
    lines[:] = [ABSOLUTE.sub(r"``|\1|``", line) for line in lines]


def init_signature(app, what, name, obj, options, signature, return_annotation):
    """A class whose metaclass's ``__call__`` hides its ``__init__`` (torchrl's ``EnvBase``
    and transforms: ``(*args, **kwargs)``) shown with its ``__init__``'s signature."""
    if what != "class" or signature != "(*args, **kwargs)":
        return None
    parameters = [parameter.replace(annotation=inspect.Parameter.empty)  # in the description
                  for parameter in list(inspect.signature(obj.__init__).parameters.values())[1:]]
    return str(inspect.Signature(parameters)), return_annotation


def setup(app):
    app.connect("autodoc-process-signature", init_signature)
    app.connect("missing-reference", resolve_short_name)
    app.connect("autodoc-process-docstring", literal_absolute_values)
