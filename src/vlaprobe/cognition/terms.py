"""Spellings of one belief: canonical (``left-of(a,b)``), DIARC/Prolog term (``left_of(a,b)``) and DIARC's form.

The vocabulary spells atoms ``pred(arg1,arg2)`` with hyphenated predicate names. Prolog (DIARC's tuProlog) and
ASP need predicate names that are atoms of the language, so ``left-of`` becomes ``left_of``; object names
(``akita_black_bowl_1``) are already lower-case identifiers and pass unchanged. DIARC's belief interface sorts
its terms into three forms: ``relation(o1,o2)``, ``property(o)`` and ``action(o)`` (the action head).
"""

from __future__ import annotations

import re
from typing import Literal

from vlaprobe.errors import VlaprobeError
from vlaprobe.symbols.vocabulary import ACTION_PREDICATES, PREDICATES, parse_atom

Form = Literal["relation", "property", "action"]

_IDENT = re.compile(r"[a-z][A-Za-z0-9_]*\Z")
_CANONICAL = {p.replace("-", "_"): p for p in PREDICATES}


def diarc_name(predicate: str) -> str:
    """``"in-front-of" -> "in_front_of"``: a predicate name that is a Prolog/ASP atom."""
    return predicate.replace("-", "_")


def canonical_name(name: str) -> str:
    """Inverse of :func:`diarc_name` for the vocabulary's predicates; other names pass unchanged."""
    return _CANONICAL.get(name, name)


def _check_ident(text: str, atom: str) -> None:
    if not _IDENT.match(text):
        raise VlaprobeError(
            f"{text!r} in atom {atom!r} is not a Prolog/ASP identifier (lower-case letter, then letters, "
            "digits or _); rename the object"
        )


def diarc_term(atom: str) -> str:
    """``"left-of(a,b)" -> "left_of(a,b)"``: the atom as a DIARC (tuProlog) or ASP term."""
    pred, args = parse_atom(atom)
    name = diarc_name(pred)
    for part in (name, *args):
        _check_ident(part, atom)
    return f"{name}({','.join(args)})"


def canonical_atom(term: str) -> str:
    """``"left_of(a,b)" -> "left-of(a,b)"``: a DIARC/ASP term back in the vocabulary's spelling."""
    name, args = parse_atom(term.replace(" ", ""))
    return f"{canonical_name(name)}({','.join(args)})"


def diarc_form(atom: str) -> Form:
    """DIARC's form of an atom: ``relation`` (two objects), ``property`` (one object) or ``action``."""
    pred, args = parse_atom(atom)
    if pred in ACTION_PREDICATES:
        return "action"
    return "relation" if len(args) == 2 else "property"
