"""Issue 14 item 3(a), the head's share inside one network (evaluation only): SMD's output (the mixture's mode) against
the disparity of its own DispNet backbone (the same weights, the head skipped), on the given data specs.

The backbone of ``SMDNet`` is a ``DispNet``; its weights are written to a temporary dispnet weights file and run
through the ``dispnet`` matcher (same padding and range handling as ``smd``); both as trained, without the left-right
check that each runs by default (``smd-nolr`` and ``dispnet-nolr`` of real_pairs.py); with ``--lr-check`` both as they
run by default (each with its left-right check, then the shared fill: the same post-processing on both sides; the
backbone without the weighted median that is ``dispnet``'s default since the thirty-seventh session, ``dispnet-nowmf``,
since ``smd`` had none then); with ``--now`` both as they run by default since the thirty-seventh session (check, fill,
weighted median on both sides).

    python docs/experiments/smd_head_vs_backbone.py [--lr-check | --now] [WEIGHTS.pt] "real;synthetic:32"
"""
import os
import subprocess
import sys
import tempfile

from stereonet.models.weights import default_weights_path, load_weights, save_weights

checked = "--lr-check" in sys.argv[1:]
now = "--now" in sys.argv[1:]
args = [a for a in sys.argv[1:] if a not in ("--lr-check", "--now")]
smd_file = args[0] if len(args) > 1 else str(default_weights_path("smd"))
specs = args[-1] if args else "real"
head, backbone = ("smd", "dispnet") if now else ("smd-lr", "dispnet-nowmf") if checked else ("smd-nolr", "dispnet-nolr")
net, info = load_weights(smd_file, expected="smd")
b = net.backbone
# the backbone's own configuration (its matching too: a census backbone read as a learned-feature one would load the
# same tensors and compute something else; this script predates census backbones and missed it until now)
config = {k: v for k, v in info["config"].items() if k in ("max_disp", "channels", "aggregation", "upsample",
                                                           "matching", "groups", "refine_radius")}
with tempfile.TemporaryDirectory() as tmp:
    backbone_file = os.path.join(tmp, "smd_backbone.pt")
    save_weights(backbone_file, "dispnet", config, b)
    here = os.path.dirname(os.path.abspath(__file__))
    for spec in specs.split(";"):
        subprocess.run([sys.executable, os.path.join(here, "real_pairs.py"),
                        f"smd-head={head}@{smd_file},smd-backbone={backbone}@{backbone_file}", spec,
                        os.path.join(tmp, "pairs.json")], check=True)
