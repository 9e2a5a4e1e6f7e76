"""The documentation site's reference (docs/api.rst, built by Sphinx in CI with warnings as
errors): every public name of ``torchpark`` is listed, and every object listed carries a
docstring, as does each public method and property its class defines (an override may
inherit its base's)."""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

import torchpark

API = Path(__file__).resolve().parents[1] / "docs" / "api.rst"


def listed() -> list[str]:
    """The dotted names of docs/api.rst's tables (relative to its ``currentmodule``)."""
    text = API.read_text()
    module = re.search(r"\.\. currentmodule:: (\S+)", text).group(1)
    return [f"{module}.{name}" for name in
            re.findall(r"^   ([A-Za-z_][\w.]*)$", text, re.M)]


def resolve(dotted: str) -> object:
    module, _, name = dotted.rpartition(".")
    return getattr(importlib.import_module(module), name)


def undocumented(obj: object, name: str) -> list[str]:
    """``name`` and its class's public methods and properties that have no docstring."""
    missing = [] if inspect.getdoc(obj) else [name]
    if inspect.isclass(obj):
        for attr, value in vars(obj).items():
            if attr.startswith("_") or not (callable(value) or isinstance(value, property)):
                continue
            if not any(getattr(vars(base).get(attr), "__doc__", None) for base in obj.__mro__):
                missing.append(f"{name}.{attr}")
    return missing


def test_every_public_name_is_on_the_site_with_its_docstrings():
    objects = {name: resolve(name) for name in listed()}
    on_site = {id(obj) for obj in objects.values()}
    public = [name for name in torchpark.__all__ if callable(getattr(torchpark, name))]
    assert [name for name in public if id(getattr(torchpark, name)) not in on_site] == []
    assert [m for name, obj in objects.items() for m in undocumented(obj, name)] == []


def test_the_rule_names_what_lacks_a_docstring():
    class Documented:
        """Has one."""

        def step(self) -> None:
            """Has one."""

    class Bare(Documented):
        def step(self) -> None:  # an override: the base's docstring holds
            pass

        def extra(self) -> None:
            pass

        @property
        def size(self) -> int:
            return 1

    assert undocumented(Documented, "Documented") == []
    assert undocumented(Bare, "Bare") == ["Bare.extra", "Bare.size"]
