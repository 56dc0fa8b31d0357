"""Per render (data_gen difficulty 2, 96x192, seeds 12-31): bad-2 of the visible pixels dispnet's left-right check
rejects divided by that of the accepted ones, for the thirty-sixth session's file (shipped until the forty-first) and
the 4x file (the property of tests/matchers/test_learned.py::test_dispnet_lr_check_finds_the_occlusions_of_a_render,
which checked it on seed 12 only until the forty-first session and now pools eight renders).
Run: OMP_NUM_THREADS=2 python docs/experiments/lr_reject_ratio.py"""
import torch

import data_gen
from stereonet.matchers import match

torch.set_grad_enabled(False)
for ck in ("docs/experiments/weights/dispnet_noc_long.pt", "docs/experiments/weights/dispnet_long4x.pt"):
    ratios = []
    for seed in range(12, 32):
        item = data_gen.SyntheticStereo(1, seed=seed, difficulty=2, height=96, width=192)[0]
        out = match("dispnet", item["left"][None], item["right"][None], item["max_disp"], wmf_radius=0, checkpoint=ck)
        vis = ~item["occlusion"][None] & item["valid"][None]
        bad = (out.disparity - item["disparity"][None]).abs() > 2
        r, a = bad[vis & ~out.valid].float().mean(), bad[vis & out.valid].float().mean()
        ratios.append(float(r / a) if a > 0 else float("inf"))
    print(ck, "ratio rejected/accepted bad-2 over seeds 12-31:", [round(x, 2) for x in ratios],
          "below 2:", sum(x < 2 for x in ratios))
