#!/usr/bin/env bash
# The defect corpus of issue 48: imperfect targets (ncflow make-pairs --defects) on four bases, each
# defect alone and all combined, plus a 12k-vertex pair (source decimated for training) clean, with fins
# and with every defect, and Fox with a coarse target (904 faces) clean, as a soup and with every defect:
#   bases: Fox (Walk, t = 0 -> 0.35 s, retriangulated), a generated quadruped galloping, a generated
#   humanoid, MANO rows 0 -> 777 (retriangulated);
#   cases: clean, soup, degenerate, duplicates, stray, fins, fragment, fragment-flipped, pinch, all
#   (degenerate, duplicates, stray, fins, fragment, pinch, then soup).
# The ground truth is kept for the target's own vertices (the new ones of fins, fragments, pinches and
# stray vertices have none), so the geodesic AUC is comparable with the clean pair's. Needs ../shared/data
# (MANO model, Fox.glb; those bases are skipped, with a message, when missing). Building takes about two
# minutes; the benchmark about 1-2 min per pair on 2 cores.
#   bash benchmarks/defects.sh [WORK_DIR] [--pairs-only | ncflow benchmark options...]
# (default ./defects; --pairs-only: build WORK_DIR/pairs/all.csv and stop).
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
DATA="$(cd "$HERE/../.." && pwd)/shared/data"
WORK="defects"
if [[ $# -gt 0 && "$1" != --* ]]; then WORK="$1"; shift; fi
PAIRS_ONLY=0
if [[ $# -gt 0 && "$1" == "--pairs-only" ]]; then PAIRS_ONLY=1; shift; fi
mkdir -p "$WORK" && cd "$WORK"
start=$SECONDS
ALL="degenerate,duplicates,stray,fins,fragment,pinch,soup"
CASES=(clean soup degenerate duplicates stray fins fragment fragment-flipped pinch all)

build() {  # build NAME CASE make-pairs-options...
  local name=$1 case=$2
  shift 2
  local defects=()
  [[ $case == all ]] && defects=(--defects "$ALL")
  [[ $case != all && $case != clean ]] && defects=(--defects "$case")
  ncflow make-pairs --overwrite "$@" "${defects[@]}" "pairs/${name}_${case}" >/dev/null
}

for case in "${CASES[@]}"; do
  if [[ -f "$DATA/gltf/Fox.glb" ]]; then
    build fox "$case" --gltf "$DATA/gltf/Fox.glb" --animation Walk --times 0,0.35 --retriangulate
  fi
  build quadruped "$case" --kind quadruped --seed 30 --articulation gallop
  build humanoid "$case" --kind humanoid --seed 31
  if [[ -f "$DATA/mano/mano_right.npz" ]]; then
    build mano "$case" --mano "$DATA/mano/mano_right.npz" --poses 0,777 --retriangulate --seed 2
  fi
done
[[ -f "$DATA/gltf/Fox.glb" ]] || echo "skipping Fox: $DATA/gltf/Fox.glb not found" >&2
[[ -f "$DATA/mano/mano_right.npz" ]] || echo "skipping MANO: $DATA/mano/mano_right.npz not found" >&2
for case in clean fins all; do
  build quadruped12k "$case" --kind quadruped --seed 30 --articulation gallop --resolution 110 --target-resolution 100
done
if [[ -f "$DATA/gltf/Fox.glb" ]]; then  # a coarse target: as a soup, more vertices than the overlap test's 1000, few faces
  for case in clean soup all; do
    build foxcoarse "$case" --gltf "$DATA/gltf/Fox.glb" --animation Walk --times 0,0.35 --retriangulate --target-resolution 24
  done
fi

python3 "$HERE/merge_pairs.py" pairs
echo "built the pairs in $((SECONDS - start)) s"
[[ $PAIRS_ONLY == 1 ]] && exit 0

ncflow benchmark pairs/all.csv --out report "$@"
sed -n '/^## Runs/,$p' report/report.md
