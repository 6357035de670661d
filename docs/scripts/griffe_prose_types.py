"""A griffe extension for the house docstring style ``name : what it is, in words``.

cooploc's numpy-style docstrings put the description on the ``name :`` line itself
(``z : (M, dz) measured values.``), where numpydoc expects a type. Read literally, the
API pages would show the description in the *Type* column, in code font, and leave the
*Description* column empty. For every parameter, attribute and return entry whose "type"
is prose (not a Python expression), this moves it to the front of the description and
takes the type from the signature's annotation instead. A reStructuredText
``.. math::`` line becomes ``$$ … $$`` (typeset by arithmatex and MathJax), with a
trailing ``(`name`)`` reference kept as text after it. The docstrings stay as they are.
"""

from __future__ import annotations

import re
from functools import cached_property
from typing import Any

import griffe

# `.. math:: body` and the more-indented lines that continue it
_MATH = re.compile(r"^(?P<indent>[ ]*)\.\. math::[ ]*(?P<body>.+(?:\n(?P=indent)[ ]+\S.*)*)", re.MULTILINE)
_CODE_REF = re.compile(r"\s*\(`[^`]+`\)[,.;]?")

_SECTIONS = (griffe.DocstringSectionParameters, griffe.DocstringSectionAttributes,
             griffe.DocstringSectionOtherParameters, griffe.DocstringSectionReturns)


def _is_prose(annotation: Any) -> bool:
    # griffe keeps an annotation it could not parse as an expression as a plain string
    return isinstance(annotation, str) and (" " in annotation.strip() or annotation.endswith("."))


def _declared(obj: griffe.Object, name: str) -> Any:
    """The annotation of parameter or member `name` of `obj`, if it declares one."""
    if isinstance(obj, griffe.Function):
        for parameter in obj.parameters:
            if parameter.name == name:
                return parameter.annotation
    member = obj.members.get(name) if hasattr(obj, "members") else None
    return getattr(member, "annotation", None) if member is not None and not member.is_alias else None


def _fix(obj: griffe.Object, sections: list[griffe.DocstringSection]) -> None:
    for section in sections:
        if not isinstance(section, _SECTIONS):
            continue
        for item in section.value:
            if not _is_prose(item.annotation):
                continue
            words = item.annotation.strip()
            item.description = f"{words} {item.description}".strip() if item.description else words
            item.annotation = (obj.returns if isinstance(section, griffe.DocstringSectionReturns)
                               and isinstance(obj, griffe.Function) else _declared(obj, item.name))


def _math_block(match: re.Match[str]) -> str:
    body = " ".join(line.strip() for line in match["body"].splitlines())
    refs = "".join(ref.strip() + " " for ref in _CODE_REF.findall(body)).strip()
    math = _CODE_REF.sub("", body).strip().rstrip(",.;")
    return f"{match['indent']}$$ {math} $$" + (f"\n\n{match['indent']}{refs}" if refs else "")


class _ProseDocstring(griffe.Docstring):
    """A docstring whose parsed sections get `_fix`: parsed when first rendered, as usual
    (after every extension has run, so that dataclass signatures are complete)."""

    @cached_property
    def parsed(self) -> list[griffe.DocstringSection]:
        self.value = _MATH.sub(_math_block, self.value)
        sections = self.parse()
        if self.parent is not None:
            _fix(self.parent, sections)
        return sections


def _walk(obj: griffe.Object) -> None:
    if obj.docstring is not None:
        obj.docstring.__class__ = _ProseDocstring
    for member in obj.members.values():
        if not member.is_alias and member.parent is obj:
            _walk(member)


class ProseTypes(griffe.Extension):
    """Move prose written where numpydoc puts a type into the description."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        _walk(pkg)
