"""The perturbation draws of the goals ``--perturb`` took before the drawers and conjunctions (issue 36) are
bitwise the same: a shipped model's training data depends on them. The digests below were computed by main's
``rollout/perturb.py`` at 3d12210 (before the drawers' keep-out); a change to the draws, the spots or the order of
the random numbers changes them. The keep-out (a drawer's way) is tested beside: it must keep spots off its box."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
from tests.collection.fakes import SCENE, FakeEnv

from vlaprobe.rollout import EpisodeControl
from vlaprobe.rollout.perturb import (
    CLEARANCE,
    KINDS,
    Perturber,
    PerturbSpec,
    free_spot,
    nearest_free_spot,
)
from vlaprobe.symbols import Goal, WorldState

SPOTS_DIGEST = "7353a0fc4e0078976c53915d7db9496701999cd7f0759185bc60d5fe71de0e40"
PLANS_DIGEST = "21bdd1d1142ba1ac0a401c398c26f0847c2c22773b433d02a126c52955fdad55"


def world(pos: np.ndarray, half: float) -> WorldState:
    env = FakeEnv(0, None)
    env.reset(0)
    return dataclasses.replace(
        env.world_state(), pos=pos, aabb_lo=pos - half, aabb_hi=pos + half, region_pos=np.zeros((1, 3))
    )


def random_world(k: int) -> WorldState:
    r = np.random.default_rng(k)
    pos = np.c_[r.uniform(-0.2, 0.15, (3, 2)), np.full(3, 0.94)]
    return world(pos, float(r.uniform(0.02, 0.08)))


def spots_digest() -> str:
    """free_spot (anywhere, near an object) and nearest_free_spot on 300 random worlds."""
    h = hashlib.sha256()
    for k in range(300):
        w = random_world(k)
        near = w.pos[1] if k % 2 else None
        for xy in (
            free_spot(w, 0, np.random.default_rng(k), near=near, base=(-0.66, 0.0)),
            nearest_free_spot(w, 0, np.random.default_rng(k), w.pos[2], base=(-0.66, 0.0)),
        ):
            h.update(b"none" if xy is None else np.asarray(xy, dtype=np.float64).tobytes())
    return h.hexdigest()


def plans_digest() -> str:
    """Perturbers of 200 seeds onto an object and onto a fixture's region: their draws, then the rows and spots
    of their moves along a made-up episode (6 rows before a grasp, 20 held rows, then success)."""
    h = hashlib.sha256()
    for seed in range(200):
        w = random_world(seed)
        for place in ("plate", "cabinet_top"):
            spec = PerturbSpec(drop=0.5, displace=0.3 + 0.7 * (seed % 2), knock_off=0.6)
            perturber, control = (
                Perturber(spec, seed, SCENE, Goal("bowl", place), (-0.66, 0.0), 600),
                EpisodeControl(),
            )
            h.update(repr([(p.kind, p.after) for p in perturber.planned]).encode())
            for t in range(60):
                grasped, success = 6 <= t < 26, t >= 26
                kind = perturber.observe(t, w, grasped, success, control)
                move = control.take_move()
                h.update(f"{t}{kind}".encode())
                if move is not None:
                    h.update(np.asarray(move[1], dtype=np.float64).tobytes())
            h.update(repr([(p.kind, p.row, p.missed) for p in perturber.planned]).encode())
    return h.hexdigest()


def test_spots_and_plans_are_those_of_before() -> None:
    assert spots_digest() == SPOTS_DIGEST
    assert plans_digest() == PLANS_DIGEST


def test_no_spot_lands_on_a_keep_out_box_and_without_it_some_do() -> None:
    """A drawer's way (a box across the workspace's middle): no spot's footprint overlaps it; without it, some do."""
    w = world(np.array([[0.1, 0.25, 0.94], [0.12, -0.15, 0.94], [-0.2, -0.15, 0.94]]), 0.03)
    box = (np.array([-0.1, -0.3]), np.array([0.05, 0.1]))
    rng = np.random.default_rng(0)

    def on_box(xy: np.ndarray | None) -> bool:
        assert xy is not None
        return bool(np.all(xy + 0.03 + CLEARANCE >= box[0]) and np.all(xy - 0.03 - CLEARANCE <= box[1]))

    assert not any(on_box(free_spot(w, 0, rng, keep_out=(box,))) for _ in range(200))
    assert not any(on_box(nearest_free_spot(w, 0, rng, np.zeros(3), keep_out=(box,))) for _ in range(20))
    assert any(on_box(free_spot(w, 0, rng)) for _ in range(200))


def test_a_perturber_reads_its_keep_out_when_a_move_is_due() -> None:
    w = world(np.array([[0.1, 0.25, 0.94], [0.12, -0.15, 0.94], [-0.2, -0.15, 0.94]]), 0.03)
    box = (np.array([-0.1, -0.3]), np.array([0.05, 0.1]))
    reads: list[int] = []

    def keep_out() -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        reads.append(1)
        return (box,)

    spec = PerturbSpec(**{k: 1.0 for k in KINDS if k != "drop"})
    for seed in range(20):
        perturber = Perturber(spec, seed, SCENE, Goal("bowl", "cabinet_top"), keep_out=keep_out)
        control = EpisodeControl()
        for t in range(40):
            perturber.observe(t, w, False, t >= 26, control)
            move = control.take_move()
            if move is not None:
                xy = np.asarray(move[1])
                assert np.any(xy + 0.03 + CLEARANCE < box[0]) or np.any(xy - 0.03 - CLEARANCE > box[1])
    assert len(reads) == 40  # one displacement and one knock-off per episode
