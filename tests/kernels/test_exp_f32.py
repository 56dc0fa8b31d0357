"""exp_f32, the vectorisable float32 exp of the AD-Census kernels: within 1 ulp of the exact value."""

from __future__ import annotations

import numba
import numpy as np

from stereonet.kernels.cost import exp_f32, float32_from_bits


@numba.njit(cache=False)
def _exp_all(x, out):
    for i in range(x.shape[0]):
        out[i] = exp_f32(x[i])


def test_exp_f32_is_within_one_ulp_of_exp_over_the_normal_range():
    x = np.concatenate([np.linspace(-87.0, 88.0, 400_001), [0.0, -0.0, 1e-8, -1e-8, np.log(2.0), -np.log(2.0)]])
    x = x.astype(np.float32)
    out = np.empty_like(x)
    _exp_all(x, out)
    exact = np.exp(x.astype(np.float64))
    ulp = np.spacing(exact.astype(np.float32)).astype(np.float64)
    assert float(np.max(np.abs(out - exact) / ulp)) <= 1.0
    assert out[x == 0.0].tolist() == [1.0, 1.0]


def test_exp_f32_clamps_outside_the_normal_range():
    """Below -87 the result stays at e^-87 (a normal float, ~1.6e-38) instead of a subnormal or 0; above 88 at
    e^88: finite, never inf or nan."""
    x = np.array([-1e6, -200.0, -87.5, 89.0, 1e6], dtype=np.float32)
    out = np.empty_like(x)
    _exp_all(x, out)
    assert np.all(np.isfinite(out)) and np.all(out > 0)
    assert np.allclose(out[:3], np.exp(np.float32(-87.0)), rtol=1e-6)
    assert np.allclose(out[3:], np.exp(np.float32(88.0)), rtol=1e-6)


@numba.njit(cache=False)
def _bits(k):
    return float32_from_bits(k)


def test_float32_from_bits_is_the_ieee_bit_pattern():
    for value in (1.0, -2.5, 3.0e-38, 1.0e38):
        bits = int(np.array([value], dtype=np.float32).view(np.int32)[0])
        assert _bits(np.int64(bits)) == np.float32(value)
        assert _bits(np.int32(bits)) == np.float32(value)
