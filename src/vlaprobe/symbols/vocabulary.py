"""The symbolic vocabulary: atoms enumerated from a scene's typed objects, in a fixed documented order.

Atoms are spelled ``pred(arg1,arg2)`` (DIARC's predicate syntax, no spaces). Order (the order of every label
vector this package writes):

object state
  1. ``behind(a,b)``, 2. ``in-front-of(a,b)``, 3. ``left-of(a,b)``, 4. ``right-of(a,b)``: ordered pairs of
     distinct tabletop objects, ``a`` major, both in ``Scene.tabletop`` order;
  5. ``on(a,b)``: ``a`` pickupable, ``b`` any other tabletop object;
  6. ``on-table(a)``: tabletop objects;
  7. ``inside(a,c)``: ``a`` pickupable, ``c`` container (drawer) or receptacle (basket, microwave, caddy...):
     ``Scene.holders``, except an object's own region (``inside_pairs``);
  8. ``open(c)``: containers, then doors (the microwave): ``Scene.openable``;
  9. ``turned-on(k)``: on-off objects.
action state
  10. ``grasped(a)``: pickupable objects;
  11. ``should-move-towards(a)``: tabletop objects.

For LIBERO-spatial (7 tabletop objects, 5 pickupable, 3 drawers, 1 stove): 4 x 42 + 30 + 7 + 15 + 3 + 1 = 224
object atoms and 5 + 7 = 12 action atoms.
"""

from __future__ import annotations

from dataclasses import dataclass

from vlaprobe.symbols.world import Scene

OBJECT_PREDICATES: tuple[str, ...] = (
    "behind",
    "in-front-of",
    "left-of",
    "right-of",
    "on",
    "on-table",
    "inside",
    "open",
    "turned-on",
)
ACTION_PREDICATES: tuple[str, ...] = ("grasped", "should-move-towards")
PREDICATES: tuple[str, ...] = OBJECT_PREDICATES + ACTION_PREDICATES
HEADS: tuple[str, ...] = ("object", "action")
"""The label heads, in the order every package lists them: object state, then action state."""


def atom(pred: str, *args: str) -> str:
    """Canonical spelling of one atom, e.g. ``atom("on", "bowl", "plate") == "on(bowl,plate)"``."""
    return f"{pred}({','.join(args)})"


def parse_atom(text: str) -> tuple[str, tuple[str, ...]]:
    """Inverse of :func:`atom`: ``"on(a,b)" -> ("on", ("a", "b"))``."""
    pred, _, rest = text.partition("(")
    if not rest.endswith(")") or not pred:
        raise ValueError(f"not an atom: {text!r}")
    return pred, tuple(rest[:-1].split(","))


def predicate_of(text: str) -> str:
    """The predicate name of an atom string."""
    return text.partition("(")[0]


@dataclass(frozen=True)
class Vocabulary:
    """The atoms of one scene, object head and action head, in the module's documented order."""

    scene: Scene
    object_atoms: tuple[str, ...]
    action_atoms: tuple[str, ...]

    def atoms(self, head: str) -> tuple[str, ...]:
        if head == "object":
            return self.object_atoms
        if head == "action":
            return self.action_atoms
        raise ValueError(f"unknown head {head!r}; expected one of {HEADS}")


def inside_pairs(scene: Scene) -> list[tuple[str, str]]:
    """(object, holder) pairs of ``inside``, ``a`` major: every pickupable and holder but an object's own region
    (a basket is never inside its own contain region)."""
    return [(a, c) for a in scene.pickupable for c in scene.holders if scene.region_parent.get(c) != a]


def build_vocabulary(scene: Scene) -> Vocabulary:
    """Enumerate every atom of ``scene`` from its typed objects."""
    tabletop, pick = scene.tabletop, scene.pickupable
    pairs = [(a, b) for a in tabletop for b in tabletop if a != b]
    objects: list[str] = []
    for pred in ("behind", "in-front-of", "left-of", "right-of"):
        objects += [atom(pred, a, b) for a, b in pairs]
    objects += [atom("on", a, b) for a in pick for b in tabletop if a != b]
    objects += [atom("on-table", a) for a in tabletop]
    objects += [atom("inside", a, c) for a, c in inside_pairs(scene)]
    objects += [atom("open", c) for c in scene.openable]
    objects += [atom("turned-on", k) for k in scene.on_off]
    actions = [atom("grasped", a) for a in pick] + [atom("should-move-towards", a) for a in tabletop]
    return Vocabulary(scene=scene, object_atoms=tuple(objects), action_atoms=tuple(actions))
