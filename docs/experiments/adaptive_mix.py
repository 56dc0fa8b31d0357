"""Issue 14, a training-free variant of ``siamese-census-sgm``: the census / learned mix weight per pixel from the
two costs' local distinctiveness (twenty-first session; rule in docs/experiments/adaptive_mix.txt).

``siamese-census-sgm`` aggregates ``(1 - a) census + a 24 (1 - cos)`` with one ``a`` (LEARNED_WEIGHT, chosen on
data_gen). Here ``a(p) = w (m_L + delta) / (w m_L + (1 - w) m_C + delta)`` with ``w`` = LEARNED_WEIGHT, ``m_C`` and
``m_L`` each cost's margin at the pixel (second-lowest cost at least 2 px from the lowest, minus the lowest; the
learned one in the same bit units, x 24), averaged over a 5x5 window, and ``delta`` = 1 bit: equal margins (or none)
give the shipped ``a`` ("odds": its odds times the margins' ratio; "ratio": ``w = 0.5``, the margins' ratio
alone, a = 0.5 at equal margins); where one cost separates its best match more clearly, its share grows. Everything else is
``sgm`` as in ``siamese-census-sgm`` (the mixed volume enters through ``extra_cost`` with weight 0 on sgm's own census).

    python docs/experiments/adaptive_mix.py "val2j;val4j"      # the rule's sets
    python docs/experiments/adaptive_mix.py real               # evaluation only, after the decision
"""
import sys

import torch
import torch.nn.functional as F
import val_sets

from stereonet.cost.volume import build_cost_volume
from stereonet.matchers.learned import LEARNED_WEIGHT, _siamese_cost, siamese_census_sgm_matcher
from stereonet.matchers.local import sgm

DELTA = 1.0  # bits
WINDOW = 5


def cost_margin(cost: torch.Tensor) -> torch.Tensor:
    """(B, D, H, W) lower = better -> (B, 1, H, W): second-lowest cost >= 2 px from the lowest, minus the lowest.
    In cost units (bits), unlike stereonet.select.cost_margin_confidence's ratio (c2 - c1) / c2: the mix compares
    the two costs' margins in the same units."""
    best, idx = cost.min(dim=1, keepdim=True)
    d = torch.arange(cost.shape[1], device=cost.device).view(1, -1, 1, 1)
    far = (d - idx).abs() >= 2
    second = torch.where(far, cost, torch.full_like(cost, float("inf"))).amin(dim=1, keepdim=True)
    return torch.nan_to_num(second - best, posinf=0.0)


def local_mean(x: torch.Tensor) -> torch.Tensor:
    r = WINDOW // 2
    return F.avg_pool2d(F.pad(x, (r, r, r, r), mode="replicate"), WINDOW, stride=1)


def adaptive_weight(census: torch.Tensor, learned_bits: torch.Tensor, w: float = LEARNED_WEIGHT) -> torch.Tensor:
    """``w = LEARNED_WEIGHT``: the shipped weight's odds scaled by the margins' ratio; ``w = 0.5``: the ratio alone."""
    m_c, m_l = local_mean(cost_margin(census)), local_mean(cost_margin(learned_bits))
    return w * (m_l + DELTA) / (w * m_l + (1.0 - w) * m_c + DELTA)


def adaptive_mix_sgm(left, right, max_disp, prior: float = LEARNED_WEIGHT, **options):
    census = build_cost_volume(left, right, max_disp, cost="census", window=1, census_window=7)
    learned_bits = 24.0 * _siamese_cost(left, right, max_disp, None).clamp(max=2.0)
    a = adaptive_weight(census, learned_bits, prior)
    mixed = (1.0 - a) * census + a * learned_bits
    return sgm(left, right, max_disp, extra_cost=(0.0, 1.0, mixed), **options)


if __name__ == "__main__":
    torch.set_num_threads(2)
    specs = sys.argv[1].split(";") if len(sys.argv) > 1 else ["val2j", "val4j"]
    val_sets.compare({"siamese-census-sgm-x": (siamese_census_sgm_matcher, {}),
                      "adaptive-odds": (adaptive_mix_sgm, {}),
                      "adaptive-ratio": (adaptive_mix_sgm, {"prior": 0.5})}, specs)
