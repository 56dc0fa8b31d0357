"""Issue 14 item 3(b), twenty-fifth session (evaluation only): AUSE (bad-2 sparsification, eval.py's fill) of `sgm`'s map on
the real pairs ranked by each classical confidence the item names: its own (cost margin x LR check), the binary
left-right agreement (|d_L(x) - d_R(x - d_L(x))| <= 1 px, the textbook LR check) and the continuous left-right
difference (LRD, Hu & Mordohai 2012). Run: python docs/experiments/sgm_lr_ause.py"""
import statistics

import torch

from stereonet import matchers, metrics
from stereonet.data import load_dataset
from stereonet.evaluation import _batch, apply_fill, expand_data_specs
from stereonet.select.lr_check import left_right_difference

fn = matchers.get_matcher("sgm")
rows = {}
for spec in expand_data_specs("real"):
    ds = load_dataset(spec)
    for i in range(len(ds)):
        it = ds[i]
        l, r = _batch(it["left"]).float(), _batch(it["right"]).float()
        md = int(it["max_disp"])
        gt, gv = _batch(it["disparity"]).float(), _batch(it["valid"]).bool()
        with torch.no_grad():
            out = fn(l, r, md)
            outr = fn(r.flip(-1), l.flip(-1), md)
        dr = apply_fill(outr).disparity.flip(-1)
        d = apply_fill(out).disparity
        lrd = left_right_difference(d, dr)  # +inf where the match leaves the right image
        name = f"{spec.split(':')[0]}/{it.get('name', i)}"
        a = dict(
            own=metrics.sparsification_ause(d, gt, gv, confidence=out.confidence),
            lr_binary=metrics.sparsification_ause(d, gt, gv, confidence=(lrd <= 1).float()),
            lrd=metrics.sparsification_ause(d, gt, gv, uncertainty=lrd),
            bad2=metrics.evaluate(d, gt, gv, see=False)["bad2"])
        rows[name] = a
        print(name, {k: round(v, 2) for k, v in a.items()})
for k in ("own", "lr_binary", "lrd", "bad2"):
    print(k, "median", round(statistics.median(r[k] for r in rows.values()), 2))
