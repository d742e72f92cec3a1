"""Symbols and detectors: the vocabulary of atoms and the functions that ground them in a world state."""

from vlaprobe.symbols.detectors import Labeler
from vlaprobe.symbols.vocabulary import (
    ACTION_PREDICATES,
    HEADS,
    OBJECT_PREDICATES,
    PREDICATES,
    Vocabulary,
    atom,
    build_vocabulary,
    parse_atom,
    predicate_of,
)
from vlaprobe.symbols.world import Articulation, Goal, Scene, WorldState

__all__ = [
    "ACTION_PREDICATES",
    "HEADS",
    "OBJECT_PREDICATES",
    "PREDICATES",
    "Articulation",
    "Goal",
    "Labeler",
    "Scene",
    "Vocabulary",
    "WorldState",
    "atom",
    "build_vocabulary",
    "parse_atom",
    "predicate_of",
]
