"""``python -m stereonet.warmup`` (run by ``make setup``) runs every classical matcher's compiled path once."""

from __future__ import annotations

from stereonet import matchers
from stereonet.warmup import main, warm_up


def test_warm_up_runs_every_classical_matcher_and_compiles_the_sgm_kernel():
    from stereonet.kernels import filters as _filters_numba
    from stereonet.kernels import sgm as _sgm_numba

    steps = dict(warm_up(verbose=False))
    classical = [n for n in matchers.available() if matchers.spec(n).kind == "classical"]
    assert set(classical) <= set(steps) and {"fill", "weighted median", "data_gen"} <= set(steps)
    assert _filters_numba.weighted_median_kernel.signatures  # sgm-refine's last step
    # compiled (or loaded from the on-disk cache) in this process: the 16-bit path of sgm's default (census)
    # and the float32 one of siamese-census-sgm's mixed cost
    assert _sgm_numba._sweep_i16.signatures and _sgm_numba.p2_maps_fixed.signatures
    assert _sgm_numba._sweep.signatures


def test_main_quiet_prints_nothing(capsys):
    assert main(["--quiet"]) == 0
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
