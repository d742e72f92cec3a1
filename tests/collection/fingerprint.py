"""Per-array fingerprints of an activation store, to check that a refactor leaves collection unchanged.

A fingerprint holds, per episode, its :class:`EpisodeInfo` fields and, per array, dtype, shape, a SHA-256 of
the bytes and (for float arrays) sums that a tolerance comparison can use where a float model output may
differ in its last bits on another machine. ``python -m tests.collection.fingerprint STORE OUT.json``
writes one.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from vlaprobe.collection.store import ActivationStore

INFO_FIELDS = ("key", "task", "init", "attempt", "success", "length", "seed", "driver")


def array_fingerprint(a: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(a)
    out: dict[str, Any] = {
        "dtype": str(a.dtype),
        "shape": list(a.shape),
        "sha256": hashlib.sha256(a.tobytes()).hexdigest(),
    }
    if a.dtype.kind == "f":
        x = np.nan_to_num(a.astype(np.float64), nan=0.0)
        out["sum"] = float(x.sum())
        out["abs_sum"] = float(np.abs(x).sum())
        out["nan"] = int(np.isnan(a).sum())
    return out


def store_fingerprint(path: str | Path) -> dict[str, Any]:
    store = ActivationStore.open(path)
    episodes = {}
    for info, arrays in store.iter_episodes():
        episodes[info.key] = {
            "info": {k: getattr(info, k) for k in INFO_FIELDS},
            "arrays": {name: array_fingerprint(arrays[name]) for name in arrays},
        }
    return {
        "atom_names": store.atom_names,
        "num_hidden_states": store.num_hidden_states,
        "hidden_size": store.hidden_size,
        "episodes": episodes,
    }


def compare(
    expected: dict[str, Any],
    actual: dict[str, Any],
    *,
    skip: tuple[str, ...] = (),
    float_tolerance: dict[str, float] | None = None,
) -> list[str]:
    """Differences between two fingerprints (empty when equal).

    Arrays named in ``skip`` are not compared. Arrays in the expected fingerprint must exist and match;
    new arrays in ``actual`` are allowed (a newer WorldState may have more fields). Arrays named in
    ``float_tolerance`` compare dtype, shape, NaN count and sums to that relative tolerance instead of bytes.
    """
    tol = float_tolerance or {}
    problems = []
    for key in ("atom_names", "num_hidden_states", "hidden_size"):
        if expected[key] != actual[key]:
            problems.append(f"{key} differs")
    if sorted(expected["episodes"]) != sorted(actual["episodes"]):
        return [*problems, f"episodes {sorted(actual['episodes'])} != {sorted(expected['episodes'])}"]
    for key, ep in expected["episodes"].items():
        got = actual["episodes"][key]
        info = {k: got["info"].get(k) for k in ep["info"]}
        if info != ep["info"]:
            problems.append(f"{key}: info {info} != {ep['info']}")
        for name, fp in ep["arrays"].items():
            if name in skip:
                continue
            if name not in got["arrays"]:
                problems.append(f"{key}/{name}: missing")
                continue
            g = got["arrays"][name]
            if name in tol:
                same = all(fp[k] == g[k] for k in ("dtype", "shape", "nan")) and all(
                    np.isclose(fp[k], g[k], rtol=tol[name], atol=tol[name]) for k in ("sum", "abs_sum")
                )
            else:
                same = all(fp[k] == g[k] for k in ("dtype", "shape", "sha256"))
            if not same:
                problems.append(f"{key}/{name}: {g} != {fp}")
    return problems


if __name__ == "__main__":
    Path(sys.argv[2]).write_text(json.dumps(store_fingerprint(sys.argv[1]), indent=1) + "\n")
