"""The cognition: a belief store fed per step by the probes (or any source of truth values), declarative
consistency rules evaluated by clingo, goal and subgoal tracking, and the DIARC spelling of it all.

Stands on its own: numpy and clingo, no simulator and no torch (only loading probes needs torch).

    from vlaprobe.cognition import Cognition
    cog = Cognition(object_atoms, action_atoms, goal)
    cs = cog.step(object_values, action_values)    # -> CognitionStep
"""

from vlaprobe.cognition.beliefs import BeliefStore, Interval
from vlaprobe.cognition.core import Cognition, CognitionStep, Violation
from vlaprobe.cognition.readout import Assignment, ProbeReadout
from vlaprobe.cognition.solver import RuleEngine, shipped_rules
from vlaprobe.cognition.subgoals import Event, SubgoalState
from vlaprobe.cognition.terms import canonical_atom, diarc_form, diarc_term
from vlaprobe.configs.monitor import CognitionConfig

__all__ = [
    "Assignment",
    "BeliefStore",
    "Cognition",
    "CognitionConfig",
    "CognitionStep",
    "Event",
    "Interval",
    "ProbeReadout",
    "RuleEngine",
    "SubgoalState",
    "Violation",
    "canonical_atom",
    "diarc_form",
    "diarc_term",
    "shipped_rules",
]
