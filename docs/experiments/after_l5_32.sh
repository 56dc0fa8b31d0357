#!/usr/bin/env bash
# Fourteenth session: what runs after docs/experiments/siamese-quick-jitter32-farneg-l5.yaml has finished (written
# while it trained, before its outcome). RUN = the folder train.py ran in.
#   bash docs/experiments/after_l5_32.sh /tmp/l5w32
# 1. export the best checkpoint, keep the resumable last.ckpt;
# 2. the selection set of every candidate (val_jitter_compare.py) -> the shipping rule in the config's header;
# 3. if this run ships: the fused weight re-chosen on data_gen validation (choose_fused_weight.py, seeds 5150/5151).
#    Rule for 3, fixed here before the run's outcome: among a in {0.75, 0.85, 0.9, 0.95}, the weight with the lowest
#    bad-2 on both val2 and val4; if no weight is lowest on both, the current 0.9 stays.
set -euo pipefail
RUN=$1
cd "$(dirname "$0")/../.."
PY=.venv/bin/python
CK=$RUN/lightning_logs/siamese-quick-jitter32-farneg-l5/checkpoints
BEST=$(ls "$CK"/best-step=*.ckpt | head -1)
echo "best checkpoint: $BEST"
$PY -m stereonet.training.export weights "$BEST" docs/experiments/weights/siamese_jitter32_farneg_l5.pt
cp "$CK/last.ckpt" docs/experiments/checkpoints/siamese-quick-jitter32-farneg-l5-last.ckpt
$PY docs/experiments/val_jitter_compare.py stereonet/weights/siamese.pt docs/experiments/weights/siamese_c16_l5.pt \
    docs/experiments/weights/siamese_jitter32_farneg_l5.pt | tee /tmp/l5_32_compare.txt
