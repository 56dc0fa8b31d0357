"""SMD uncertainty candidates (b, ead, p2; see smd_uncertainty.txt) ranked by bad-2 sparsification AUSE.

    python docs/experiments/smd_uncertainty.py [SPEC ...]     (default: synthetic:32 val2k val4k)
"""
import statistics
import sys

import torch

from stereonet.matchers import match
from stereonet.metrics import sparsification_ause

sys.path.insert(0, "docs/experiments")
from val_sets import load  # noqa: E402


def laplace_tail(mu, b, m, t):
    """P(|X - m| > t) for X ~ Laplace(mu, b)."""
    lo, hi = m - t, m + t
    cdf = lambda x: torch.where(x < mu, 0.5 * torch.exp((x - mu) / b), 1 - 0.5 * torch.exp(-(x - mu) / b))
    return 1 - (cdf(hi) - cdf(lo))


def candidates(out):
    e = out.extras
    first = e["pi"] / e["b1"] >= (1 - e["pi"]) / e["b2"]  # the chosen component, as mode_disparity
    pk = torch.where(first, e["pi"], 1 - e["pi"])
    bk, bj = torch.where(first, e["b1"], e["b2"]), torch.where(first, e["b2"], e["b1"])
    mk, mj = torch.where(first, e["mu1"], e["mu2"]), torch.where(first, e["mu2"], e["mu1"])
    gap = (mk - mj).abs()
    ead = pk * bk + (1 - pk) * (gap + bj * torch.exp(-gap / bj))
    p2 = pk * torch.exp(-2.0 / bk) + (1 - pk) * laplace_tail(mj, bj, mk, 2.0)
    return {"b": out.uncertainty, "ead": ead, "p2": p2}


def main(specs):
    for spec in specs:
        ds = load(spec)
        values = {}
        for i in range(len(ds)):
            item = ds[i]
            out = match("smd", item["left"][None], item["right"][None], item["max_disp"])
            for name, u in candidates(out).items():
                values.setdefault(name, []).append(
                    sparsification_ause(out.disparity, item["disparity"][None], item["valid"][None], uncertainty=u))
        print(f"{spec} ({len(ds)} pairs): median AUSE " + "  ".join(
            f"{k} {statistics.median(v):.3f}" for k, v in values.items()), flush=True)
        print("  per pair " + " | ".join(f"{k}: " + " ".join(f"{x:.2f}" for x in v) for k, v in values.items()))


if __name__ == "__main__":
    main(sys.argv[1:] or ["synthetic:32", "val2k", "val4k"])
