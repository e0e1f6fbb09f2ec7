#!/usr/bin/env bash
# The hard development set of issue 16: large articulations and targets turned and moved.
#   MANO (mano_right.npz): flat hand -> fist; hands_coeffs row 0 -> row 207 (a captured fist); rows
#     0->777, 100->1200, 250->900 with the target turned 20, 90 and 180 degrees and moved;
#   generated humanoids: arms crossed; a long stride turned 180 degrees and moved; a crouch;
#   generated hands: every finger curled; four curled finger joints, turned 90 degrees and moved;
#   a generated quadruped galloping, turned 45 degrees and moved;
#   CesiumMan (walk, t = 0 -> 1 s, a half cycle: the legs swap) and Fox (Walk, t = 0 -> 0.35 s).
# Every target is re-triangulated (its own vertices; face + barycentric ground truth, which a rigid
# motion of the target leaves unchanged; the motion is in pair_000/target_motion.json). Each pair is
# named after its folder. Needs ../shared/data (MANO model; the glTF files are skipped, with a
# message, when missing). Building takes about a minute; the benchmark about 3 min per pair on 2 cores.
#   bash benchmarks/hard_pairs.sh [WORK_DIR] [--pairs-only | ncflow benchmark options...]
# (default ./hard; --pairs-only: build WORK_DIR/pairs/all.csv and stop; other options, e.g.
# --jobs 2 or --preset paper, go to ncflow benchmark, which writes WORK_DIR/report/report.md).
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
DATA="$(cd "$HERE/../.." && pwd)/shared/data"
WORK="hard"
if [[ $# -gt 0 && "$1" != --* ]]; then WORK="$1"; shift; fi
PAIRS_ONLY=0
if [[ $# -gt 0 && "$1" == "--pairs-only" ]]; then PAIRS_ONLY=1; shift; fi
MANO="$DATA/mano/mano_right.npz"
GLTF="$DATA/gltf"
mkdir -p "$WORK" && cd "$WORK"
start=$SECONDS

if [[ -f "$MANO" ]]; then
  ncflow make-pairs --overwrite --mano "$MANO" --poses flat,fist --retriangulate pairs/mano_flat_fist
  ncflow make-pairs --overwrite --mano "$MANO" --poses 0,207 --retriangulate --seed 1 pairs/mano_0_207
  ncflow make-pairs --overwrite --mano "$MANO" --poses 0,777 --retriangulate --seed 2 \
    --target-rotation 20 --target-translation 0.3 pairs/mano_0_777_r20
  ncflow make-pairs --overwrite --mano "$MANO" --poses 100,1200 --retriangulate --seed 3 \
    --target-rotation 90 --target-translation 0.5 pairs/mano_100_1200_r90
  ncflow make-pairs --overwrite --mano "$MANO" --poses 250,900 --retriangulate --seed 4 \
    --target-rotation 180 --target-translation 1.0 pairs/mano_250_900_r180
else
  echo "skipping the MANO pairs: $MANO not found" >&2
fi
ncflow make-pairs --overwrite --kind humanoid --seed 20 --articulation cross pairs/humanoid_cross
ncflow make-pairs --overwrite --kind humanoid --seed 21 --articulation stride \
  --target-rotation 180 --target-translation 0.5 pairs/humanoid_stride_r180
ncflow make-pairs --overwrite --kind humanoid --seed 22 --articulation crouch pairs/humanoid_crouch
ncflow make-pairs --overwrite --kind hand --seed 20 --articulation curl pairs/hand_curl
ncflow make-pairs --overwrite --kind hand --seed 21 --large-joints 4 \
  --target-rotation 90 --target-translation 0.3 pairs/hand_curled4_r90
ncflow make-pairs --overwrite --kind quadruped --seed 20 --articulation gallop \
  --target-rotation 45 --target-translation 0.3 pairs/quadruped_gallop_r45
if [[ -f "$GLTF/CesiumMan.glb" ]]; then
  ncflow make-pairs --overwrite --gltf "$GLTF/CesiumMan.glb" --times 0,1.0 --retriangulate pairs/cesiumman_half_cycle
else
  echo "skipping CesiumMan: $GLTF/CesiumMan.glb not found" >&2
fi
if [[ -f "$GLTF/Fox.glb" ]]; then
  ncflow make-pairs --overwrite --gltf "$GLTF/Fox.glb" --animation Walk --times 0,0.35 --retriangulate pairs/fox_walk
else
  echo "skipping Fox: $GLTF/Fox.glb not found" >&2
fi

python3 "$HERE/merge_pairs.py" pairs
echo "built the pairs in $((SECONDS - start)) s"
[[ $PAIRS_ONLY == 1 ]] && exit 0

ncflow benchmark pairs/all.csv --out report "$@"
sed -n '/^## Runs/,$p' report/report.md
