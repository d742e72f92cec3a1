"""The child process that grounds users' rules under a budget (run as a script by :mod:`.budget`).

It reads one JSON line (the programs, the rules files, the memory and time limits), caps its own address space,
starts a wall-clock timer whose signal (SIGALRM, default action) ends it even inside clingo's grounder, and
prints one JSON line per program: ``ok`` with the number of ground atoms, or ``invalid`` (the parent's own
grounding then reports the error with its file and line). Imports nothing of vlaprobe: it starts fast.
"""

from __future__ import annotations

import json
import resource
import signal
import sys


def main() -> None:
    request = json.loads(sys.stdin.readline())
    limit = int(request["memory_bytes"])
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    import clingo

    print(json.dumps({"status": "ready"}), flush=True)
    signal.setitimer(signal.ITIMER_REAL, float(request["seconds"]))
    for program in request["programs"]:
        ctl = clingo.Control(["--warn=none"], logger=lambda code, message: None)
        try:
            ctl.add("base", [], program)
            for path in request["files"]:
                ctl.load(path)
            ctl.ground([("base", [])])
        except MemoryError:
            print(json.dumps({"status": "memory"}), flush=True)
            return
        except RuntimeError as exc:
            status = "memory" if "bad_alloc" in str(exc) else "invalid"
            print(json.dumps({"status": status}), flush=True)
            continue
        print(json.dumps({"status": "ok", "atoms": len(ctl.symbolic_atoms)}), flush=True)


if __name__ == "__main__":
    main()
