#!/usr/bin/env bash
# Train the three learned matchers as the shipped weights were trained, export them to weights/ and plot
# their curves. Run from the repository root; logs and checkpoints go to lightning_logs/.
# Times: ~40 min (siamese) and 58 min each (dispnet, smd: the configs' max_time), all in parallel, one thread
# each, on a 2-core CPU (the shipped dispnet/smd were trained exactly so, without the siamese run beside them).
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
