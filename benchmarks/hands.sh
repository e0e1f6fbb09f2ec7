#!/usr/bin/env bash
# The seeded hand benchmark of issue 44: 41 MANO pairs chosen by pose class from the model's 1554
# captured poses (20 random row pairs, 5 flat -> fist, 5 fist -> flat, 5 with a pinch target, 6 more
# between the classes; half of the targets turned up to 180 degrees and moved; every target
# re-triangulated) and 12 procedural hands (2-4 large finger flexions, every third one curled, half
# turned), built by benchmarks/hand_pairs.py (the selection, its thresholds and every make-pairs
# command are in WORK_DIR/pairs/selection.json); then ncflow benchmark, then the per-finger errors of
# benchmarks/fingers.py (WORK_DIR/report/fingers.json). Needs ../shared/data/mano/mano_right.npz
# (skipped, with a message, when missing) and the Python environment of ncflow. Building takes about
# 2 min; the benchmark about 3 min per pair on 2 cores.
#   bash benchmarks/hands.sh [WORK_DIR] [--pairs-only | ncflow benchmark options...]
# (default ./hands; --pairs-only: build WORK_DIR/pairs/all.csv and stop; other options, e.g. --jobs 2
# or --preset paper, go to ncflow benchmark, which writes WORK_DIR/report/report.md). The selection
# seed is HAND_SEED (default 0); another seed needs another WORK_DIR.
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
DATA="$(cd "$HERE/../.." && pwd)/shared/data"
PYTHON="${PYTHON:-python3}"
WORK="hands"
if [[ $# -gt 0 && "$1" != --* ]]; then WORK="$1"; shift; fi
PAIRS_ONLY=0
if [[ $# -gt 0 && "$1" == "--pairs-only" ]]; then PAIRS_ONLY=1; shift; fi
MANO="$DATA/mano/mano_right.npz"
if [[ ! -f "$MANO" ]]; then
  echo "skipping the hand benchmark: $MANO not found" >&2
  exit 0
fi
mkdir -p "$WORK" && cd "$WORK"
start=$SECONDS

"$PYTHON" "$HERE/hand_pairs.py" "$MANO" . --seed "${HAND_SEED:-0}"
echo "built the pairs in $((SECONDS - start)) s"
[[ $PAIRS_ONLY == 1 ]] && exit 0

ncflow benchmark pairs/all.csv --out report "$@"
sed -n '/^## Runs/,$p' report/report.md
"$PYTHON" "$HERE/fingers.py" report pairs/all.csv
