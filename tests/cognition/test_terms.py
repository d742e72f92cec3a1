"""Atom spellings: canonical, DIARC/Prolog term, DIARC's form."""

from __future__ import annotations

import pytest

from vlaprobe.cognition import canonical_atom, diarc_form, diarc_term
from vlaprobe.errors import VlaprobeError


@pytest.mark.parametrize(
    ("atom", "term", "form"),
    [
        ("left-of(a,b)", "left_of(a,b)", "relation"),
        ("in-front-of(akita_black_bowl_1,plate_1)", "in_front_of(akita_black_bowl_1,plate_1)", "relation"),
        ("on(a,b)", "on(a,b)", "relation"),
        ("on-table(a)", "on_table(a)", "property"),
        ("turned-on(flat_stove_1)", "turned_on(flat_stove_1)", "property"),
        ("grasped(a)", "grasped(a)", "action"),
        ("should-move-towards(plate_1)", "should_move_towards(plate_1)", "action"),
    ],
)
def test_spellings_round_trip(atom: str, term: str, form: str) -> None:
    assert diarc_term(atom) == term
    assert canonical_atom(term) == atom
    assert diarc_form(atom) == form


def test_names_that_are_not_prolog_atoms_are_refused() -> None:
    with pytest.raises(VlaprobeError, match="not a Prolog/ASP identifier"):
        diarc_term("on(Bowl,plate)")


def test_the_cognition_imports_without_torch_or_the_simulator() -> None:
    import subprocess
    import sys

    code = (
        "import sys, vlaprobe.cognition, vlaprobe.cognition.monitor; "
        "print(sorted(m for m in ('torch', 'mujoco', 'libero', 'robosuite') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
