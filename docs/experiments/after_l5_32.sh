#!/usr/bin/env bash
# Fourteenth session: what ran after docs/experiments/siamese-quick-jitter32-farneg-l5.yaml had finished (written
# while it trained, before its outcome; the steps and the fused-weight rule are in after_siamese_run.sh).
#   bash docs/experiments/after_l5_32.sh /tmp/l5w32
set -euo pipefail
exec bash "$(dirname "$0")/after_siamese_run.sh" "$1" siamese-quick-jitter32-farneg-l5 siamese_jitter32_farneg_l5
