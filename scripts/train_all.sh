#!/usr/bin/env bash
# Train the four learned weight files as the shipped ones were trained, export them to stereonet/weights/ and plot
# the curves. Run from the repository root; logs and checkpoints go to lightning_logs/.
# Two phases, because refine.pt is trained on top of another file: it reads siamese-census-sgm's maps (siamese.pt,
# fixed), the file that phase 1 has just exported. smd.pt's backbone is a committed file, the shipped dispnet.pt's
# kept copy (docs/experiments/weights/dispnet_long4x.pt, configs/smd.yaml), not this run's dispnet.pt.
#   phase 1, in parallel: siamese (29 803 steps, 32 min alone on 2 threads) and dispnet (25 916 steps, ~4.7 h alone)
#   phase 2, in parallel: smd's head (3 819 steps, 21.5 min alone) and sgm-refine (14 000 steps, 34 min alone)
# One thread each on a 2-core CPU, so each takes longer than alone (the shipped weights were each trained alone; see
# stereonet/weights/README.md); every run stops by its steps, so a slower machine only takes longer.
set -euo pipefail
PY=${PYTHON:-.venv/bin/python}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
best() { ls -t "lightning_logs/$1/checkpoints/"best-*.ckpt | head -1; }
"$PY" train.py fit --config configs/siamese.yaml & a=$!
"$PY" train.py fit --config configs/dispnet.yaml & b=$!
wait "$a"; wait "$b"  # each run's own exit status: a failed run stops the script here
for name in siamese dispnet; do
  "$PY" -m stereonet.training.export weights "$(best $name)" stereonet/weights/$name.pt
done
"$PY" train.py fit --config configs/smd.yaml & a=$!
"$PY" train.py fit --config configs/sgm-refine.yaml & b=$!
wait "$a"; wait "$b"
"$PY" -m stereonet.training.export weights "$(best smd)" stereonet/weights/smd.pt
"$PY" -m stereonet.training.export weights lightning_logs/sgm-refine/checkpoints/last.ckpt stereonet/weights/refine.pt
"$PY" -m stereonet.training.export curves stereonet/weights/curves.png \
  siamese=lightning_logs/siamese dispnet=lightning_logs/dispnet smd=lightning_logs/smd
