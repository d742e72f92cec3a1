"""The one success rule of the loop, the collection worker and the live server (hand-made sequences)."""

from __future__ import annotations

from vlaprobe.rollout import SuccessTracker


def follow(flags: str, perturb: dict[int, str] | None = None) -> list[int | None]:
    """Feed observations ("1" success, "0" not) with perturbations at some rows; the onset after each row."""
    tracker, out = SuccessTracker(), []
    for t, f in enumerate(flags):
        kind = (perturb or {}).get(t, "")
        if kind == "move":
            tracker.perturbed = True
        tracker.observe(t, f == "1")
        if kind == "drop":
            tracker.perturbed = True
        out.append(tracker.step)
    return out


def test_first_onset_counts_and_a_bounce_without_perturbation_keeps_it() -> None:
    assert follow("0011011") == [None, None, 2, 2, 2, 2, 2]


def test_after_a_perturbation_a_lost_success_no_longer_counts_and_a_new_onset_does() -> None:
    # a knock-off (a move) at row 4 takes the bowl off the plate; the expert places it again at row 6
    assert follow("0011001", {4: "move"}) == [None, None, 2, 2, None, None, 6]
    # a drop before the success: the success that follows counts from its onset; lost at the end, none
    assert follow("00110", {1: "drop"}) == [None, None, 2, 2, None]


def test_records_are_followed_by_the_same_rule() -> None:
    class Rec:
        def __init__(self, t: int, success: bool, perturbation: str = "") -> None:
            self.t, self.success, self.perturbation = t, success, perturbation

    tracker = SuccessTracker()
    for r in (Rec(0, False), Rec(1, True), Rec(2, False, "move"), Rec(3, True)):
        tracker.add(r)  # type: ignore[arg-type]
    assert tracker.step == 3 and tracker.perturbed
