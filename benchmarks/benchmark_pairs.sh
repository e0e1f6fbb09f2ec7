#!/usr/bin/env bash
# The 17-pair benchmark of benchmarks/RESULTS.md ("Benchmark, default preset"): 5 generated
# humanoids, 5 generated hands, 5 MANO pairs, CesiumMan and Fox (two animation times each), every
# target re-triangulated. Needs ../shared/data (MANO model, glTF files); about 50 min on 2 cores.
#   bash benchmarks/benchmark_pairs.sh [WORK_DIR]   (default ./ncflow-benchmark)
set -euo pipefail
DATA="$(cd "$(dirname "$0")/../.." && pwd)/shared/data"
WORK="${1:-ncflow-benchmark}"
mkdir -p "$WORK" && cd "$WORK"
ncflow make-pairs --overwrite --kind humanoid --n 5 --seed 10 pairs/humanoid
ncflow make-pairs --overwrite --kind hand --n 5 --seed 10 pairs/hand
ncflow make-pairs --overwrite --mano "$DATA/mano/mano_right.npz" --poses 0,777,100,1200,250,900,400,1500,600,1100 --retriangulate pairs/mano
ncflow make-pairs --overwrite --gltf "$DATA/gltf/CesiumMan.glb" --times 0,1.0 --retriangulate pairs/cesiumman
ncflow make-pairs --overwrite --gltf "$DATA/gltf/Fox.glb" --animation Walk --times 0,0.35 --retriangulate pairs/fox
python3 - <<'PY'
import csv
rows = []
for d in ["humanoid", "hand", "mano", "cesiumman", "fox"]:
    for r in csv.DictReader(open(f"pairs/{d}/pairs.csv")):
        rows.append({**r, **{k: f"{d}/{r[k]}" for k in ("source", "target", "skeleton", "gt")}})
with open("pairs/all.csv", "w", newline="") as fh:
    w = csv.DictWriter(fh, fieldnames=list(rows[0])); w.writeheader(); w.writerows(rows)
PY
ncflow benchmark pairs/all.csv --out report
