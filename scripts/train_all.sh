#!/usr/bin/env bash
# Train the three learned matchers as the shipped weights were trained, export them to weights/ and plot
# their curves. Run from the repository root; logs and checkpoints go to lightning_logs/.
# Times: 58 min for dispnet (its config's max_time), 3819 steps for smd (32 min alone on both cores); the siamese recipe's 29 803 steps took 1 h 37 min
# alone on both cores (fourteenth session), longer here with one thread beside the other two. All in parallel, one
# thread each, on a 2-core CPU (the shipped weights were each trained alone; see stereonet/weights/README.md).
set -euo pipefail
PY=${PYTHON:-.venv/bin/python}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
"$PY" train.py fit --config configs/siamese.yaml --data.num_workers 1 &
"$PY" train.py fit --config configs/dispnet.yaml &
"$PY" train.py fit --config configs/smd.yaml &
wait
for name in siamese dispnet smd; do
  best=$(ls -t lightning_logs/$name/checkpoints/best-*.ckpt | head -1)
  "$PY" -m stereonet.training.export weights "$best" stereonet/weights/$name.pt
done
"$PY" -m stereonet.training.export curves stereonet/weights/curves.png \
  siamese=lightning_logs/siamese dispnet=lightning_logs/dispnet smd=lightning_logs/smd
