#!/usr/bin/env bash
# What runs after a Siamese experiment of docs/experiments has finished (fourteenth session).
#   bash docs/experiments/after_siamese_run.sh RUN LOGNAME STEM
# RUN = the folder train.py ran in, LOGNAME = the config's logger name, STEM = the weights' file stem.
# 1. export the best checkpoint to docs/experiments/weights/STEM.pt, keep the resumable last.ckpt;
# 2. the selection set of every candidate (val_jitter_compare.py) -> the shipping rule in the config's header;
# 3. if the run ships: the fused weight re-chosen on data_gen validation (choose_fused_weight.py, seeds 5150/5151).
#    Rule for 3, fixed before the five-layer run's outcome: among a in {0.75, 0.85, 0.9, 0.95}, the weight with the
#    lowest bad-2 on both val2 and val4; if no weight is lowest on both, the current 0.9 stays.
set -euo pipefail
RUN=$1 LOGNAME=$2 STEM=$3
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
CK=$RUN/lightning_logs/$LOGNAME/checkpoints
BEST=$(ls "$CK"/best-step=*.ckpt | head -1)
echo "best checkpoint: $BEST"
$PY -m stereonet.training.export weights "$BEST" "docs/experiments/weights/$STEM.pt"
cp "$CK/last.ckpt" "docs/experiments/checkpoints/$LOGNAME-last.ckpt"
$PY docs/experiments/val_jitter_compare.py stereonet/weights/siamese.pt docs/experiments/weights/siamese_c16_l5.pt \
    "docs/experiments/weights/$STEM.pt" | tee "/tmp/${STEM}_compare.txt"
