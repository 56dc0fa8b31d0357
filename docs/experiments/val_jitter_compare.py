"""Synthetic validation WTA EPE of exported Siamese weights, on the clean and on the vertically jittered
validation set of configs/siamese-quick.yaml (data_gen val_seed 900000, 12 pairs, 96x192).

Selection rule, fixed before the jitter run finished: between runs, the weights with the lower EPE on the
*jittered* set (fixed offsets -1..1 row per pair) are shipped, because every real rig's rectification
leaves such errors; the clean set is reported beside it.

    python docs/experiments/val_jitter_compare.py stereonet/weights/siamese.pt [OTHER.pt ...]

A third column, ``warped``, adds offsets that vary across the image (``val_vertical_warp`` 0.5 rows at the
borders beside the 1-row offset): the selection set of the vertical-warp ablation (seventh/eighth session).
A fourth, ``jittered aa``, is the jittered set rendered anti-aliased (data_gen ``supersample`` 2, same seed and
offsets): the selection set of the anti-aliased-renders ablation (eleventh session).
A fifth, ``jittered 256x512``, is the jittered set at data_gen's default size (the size of eval.py's synthetic sets),
WTA over 0..192 (its largest disparity): the selection set of the render-size ablation (twelfth session).
"""
import sys

import torch

from stereonet.models.siamese import siamese_cost_volume
from stereonet.models.weights import load_weights
from stereonet.training.data import SyntheticStereoDataModule, collate_pairs
from stereonet.training.losses import disparity_errors


def val_epe(net, jitter: float, batch_size: int = 4, warp: float = 0.0, supersample: int = 1,
            size: tuple[int, int] = (96, 192), max_disp: int = 64) -> float:
    dm = SyntheticStereoDataModule(source="data_gen", height=size[0], width=size[1], val_pairs=12, supersample=supersample,
                                   val_seed=900000, val_vertical_jitter=jitter, val_vertical_warp=warp)
    dm.setup("fit")
    total, count = 0.0, 0
    for i in range(0, len(dm.val_items), batch_size):
        batch = collate_pairs(dm.val_items[i:i + batch_size])
        with torch.no_grad():
            b = batch["left"].shape[0]
            feats = net(torch.cat([batch["left"], batch["right"]]))
            pred = siamese_cost_volume(feats[:b], feats[b:], max_disp).argmin(dim=1, keepdim=True).float()
        total += float(disparity_errors(pred, batch["disparity"], batch["valid"])["epe"]) * b
        count += b
    return total / count


for path in sys.argv[1:]:
    net, _ = load_weights(path)
    net.eval()
    print(f"{path}: val WTA EPE clean {val_epe(net, 0.0):.3f}  jittered {val_epe(net, 1.0):.3f}  "
          f"warped {val_epe(net, 1.0, warp=0.5):.3f}  jittered aa {val_epe(net, 1.0, supersample=2):.3f}  "
          f"jittered 256x512 {val_epe(net, 1.0, size=(256, 512), max_disp=192):.3f}", flush=True)
