#!/usr/bin/env bash
# The takeover comparison's collections (docs/failures.md#the-cognition-takes-over-takeover-alarmrandom), resumable.
# Round N = init state N of tasks 0-9, one episode per task and condition, into OUT/rN/{alarm,random,none}. A round
# runs two tasks at a time through the three conditions (alarm first: random matches its takeovers), so that
# complete task x init triples accrue as it goes. A finished (round, tasks, condition) leaves a marker and is
# skipped; an interrupted collect resumes its store (same settings). No collect starts after STOP (any `date -d`
# time, e.g. "00:48 tomorrow"; empty: never stop). Options after -- go to every collect (e.g. `--takeover-until
# steps --takeover-steps 60`, the fixed-length variant; its none/ would be the same store as this one's).
#
#   bash scripts/takeover_rounds.sh OUT FIRST_ROUND LAST_ROUND [STOP] [-- collect options]
#   bash scripts/takeover_rounds.sh runs/tko2 40 49 "00:48 tomorrow"
#   python scripts/takeover_comparison.py runs/tko2/r40 runs/tko2/r41 ...
set -euo pipefail
out=$1 first=$2 last=$3
shift 3
stop=""
if [[ $# -gt 0 && $1 != -- ]]; then
    if [[ -n $1 ]]; then
        stop=$(date -d "$1" +%s)
    fi
    shift
fi
if [[ $# -gt 0 && $1 == -- ]]; then
    shift
fi
vlaprobe=${VLAPROBE:-vlaprobe}

for ((n = first; n <= last; n++)); do
    round=$out/r$n
    mkdir -p "$round"
    for tasks in "0 1" "2 3" "4 5" "6 7" "8 9"; do
        for cond in alarm random none; do
            marker=$round/.done-$cond-${tasks// /}
            [[ -f $marker ]] && continue
            if [[ -n $stop ]] && (($(date +%s) > stop)); then
                echo "$(date -u +%T) stop: past $(date -u -d "@$stop" +%T)"
                exit 0
            fi
            extra=()
            [[ $cond != none ]] && extra=(--takeover "$cond")
            [[ $cond == random ]] && extra+=(--takeover-match "$round/alarm")
            echo "$(date -u +%T) r$n tasks $tasks $cond"
            # shellcheck disable=SC2086  # $tasks: two task indices
            "$vlaprobe" collect --out "$round/$cond" --tasks $tasks --driver policy --model tiny-libero \
                --first-init "$n" --episodes-per-task 1 --max-tries-per-task 1 --keep-failed \
                --env.max-steps 300 --workers 2 --no-progress "${extra[@]}" "$@"
            touch "$marker"
        done
    done
done
echo "$(date -u +%T) done"
