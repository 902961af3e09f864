#!/usr/bin/env bash
# CPU seconds of `sage sim`'s whole process tree at rest (issue #24): one process vs process groups.
#   bash scripts/cpu_at_rest.sh --one-process|--processes [WARM_UP_S] [WINDOW_S]
# Sums utime + stime from /proc/<pid>/stat of every process in the run's session over WINDOW_S
# seconds after WARM_UP_S seconds of start-up (defaults 60 and 60). Needs the set-up .venv.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:?--one-process or --processes}; warm=${2:-60}; window=${3:-60}
SAGE_STATE_DIR=$(mktemp -d); SAGE_DATA_DIR=$(mktemp -d)
export SAGE_STATE_DIR SAGE_DATA_DIR SAGE_OPERATOR_PASSWORD=${SAGE_OPERATOR_PASSWORD:-at-rest}
log=$(mktemp)
setsid --fork .venv/bin/sage sim "$mode" >"$log" 2>&1 </dev/null
sleep 1
pid=$(pgrep -n -f "sage sim $mode") || { echo "sage sim did not start: $(tail -3 "$log")" >&2; exit 1; }
sid=$(ps -o sid= -p "$pid" | tr -d ' ')
# the whole session, whatever happens to this script (a robot left running skews the next run)
trap 'pkill -INT -s "$sid" 2>/dev/null || true; sleep 5; pkill -KILL -s "$sid" 2>/dev/null || true' EXIT
sleep "$warm"
kill -0 "$pid" 2>/dev/null || { echo "sage sim ended early: $(tail -3 "$log")" >&2; exit 1; }
tree_ticks() {
  local total=0 t
  for p in $(ps -e -o pid=,sid= | awk -v s="$sid" '$2 == s {print $1}'); do
    t=$(awk '{print $14 + $15}' "/proc/$p/stat" 2>/dev/null || echo 0)
    total=$((total + t))
  done
  echo "$total"
}
count=$(ps -e -o sid= | awk -v s="$sid" '$1 == s' | wc -l)
t0=$(tree_ticks); sleep "$window"; t1=$(tree_ticks)
hz=$(getconf CLK_TCK)
printf '{"mode": "%s", "processes": %d, "cpu_s": %.2f, "window_s": %d}\n' \
  "${mode#--}" "$count" "$(echo "($t1 - $t0) / $hz" | bc -l)" "$window"
