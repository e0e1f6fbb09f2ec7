#!/usr/bin/env bash
# The 17-pair benchmark of benchmarks/RESULTS.md ("Benchmark, default preset"): 5 generated
# humanoids, 5 generated hands, 5 MANO pairs, CesiumMan and Fox (two animation times each), every
# target re-triangulated. Needs ../shared/data (MANO model, glTF files); about 50 min on 2 cores.
#   bash benchmarks/benchmark_pairs.sh [WORK_DIR] [--pairs-only | ncflow benchmark options...]
# (default ./ncflow-benchmark; --pairs-only: build WORK_DIR/pairs/all.csv and stop).
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
DATA="$(cd "$HERE/../.." && pwd)/shared/data"
WORK="ncflow-benchmark"
if [[ $# -gt 0 && "$1" != --* ]]; then WORK="$1"; shift; fi
PAIRS_ONLY=0
if [[ $# -gt 0 && "$1" == "--pairs-only" ]]; then PAIRS_ONLY=1; shift; fi
mkdir -p "$WORK" && cd "$WORK"
ncflow make-pairs --overwrite --kind humanoid --n 5 --seed 10 pairs/humanoid
ncflow make-pairs --overwrite --kind hand --n 5 --seed 10 pairs/hand
ncflow make-pairs --overwrite --mano "$DATA/mano/mano_right.npz" --poses 0,777,100,1200,250,900,400,1500,600,1100 --retriangulate pairs/mano
ncflow make-pairs --overwrite --gltf "$DATA/gltf/CesiumMan.glb" --times 0,1.0 --retriangulate pairs/cesiumman
ncflow make-pairs --overwrite --gltf "$DATA/gltf/Fox.glb" --animation Walk --times 0,0.35 --retriangulate pairs/fox
python3 "$HERE/merge_pairs.py" pairs --keep-names
[[ $PAIRS_ONLY == 1 ]] && exit 0
ncflow benchmark pairs/all.csv --out report "$@"
