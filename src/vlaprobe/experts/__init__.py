"""The privileged scripted expert: skills that read the simulator and output 7-D actions, and the planner that
sequences them from a task's BDDL goal (docs/collection.md, "The scripted expert").

One module per skill: :mod:`~vlaprobe.experts.rim_pick` (bowls and mugs by the rim), :mod:`~.body_pick`
(boxes, cans, bottles by the body), :mod:`~.drawer` (open or close a drawer), :mod:`~.knob` (turn a stove on
or off), :mod:`~.push` (push a plate); :mod:`~.planner` turns the goal into steps.
"""

from vlaprobe.experts.planner import ScriptedExpert, Step, plan_steps

__all__ = ["ScriptedExpert", "Step", "plan_steps"]
