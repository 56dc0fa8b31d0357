"""The compiled (numba) CPU kernels, in one place, behind one backend rule (:func:`use_numba`).

Each module here is plain numba on numpy arrays and imports nothing from the rest of the package; the
torch-facing functions that call them (``stereonet.cost``, ``stereonet.aggregate``, ``stereonet.select``,
``stereonet.models.siamese``) check their inputs once and ask :func:`use_numba` which path to take. Every
kernel is tested equal to its torch reference (tests/kernels/test_kernels_vs_torch.py and the per-module
tests), and every one states its ``fastmath`` flags: none allows the compiler to assume away the NaN and
infinity sentinels.

=====================  ================================================================================
module                 kernels
=====================  ================================================================================
``kernels.cost``       census codes and Hamming volumes (uint8), box means, the learned-feature cost, the
                       mix of two volumes
``kernels.block``      the fused block engine: cost + window sums + selection row by row (``bm-*``)
``kernels.sgm``        semi-global aggregation of ``(H, W, D)`` volumes (float32 or uint8)
``kernels.dp``         scanline dynamic programming
``kernels.bp``         loopy belief propagation (one pyramid level)
``kernels.select``     WTA + sub-pixel + uniqueness + left-right check in one pass, right-view WTA
``kernels.confidence`` the cost margin of an aggregated volume
``kernels.filters``    the 3x3 median (sorting network) and the speckle filter
=====================  ================================================================================
"""

from __future__ import annotations

import numpy as np
import torch

from stereonet.checks import StereoInputError

BACKENDS = ("auto", "torch", "numba")


def use_numba(*tensors: torch.Tensor, backend: str = "auto", float32_only: bool = True) -> bool:
    """The one backend rule: whether a call with ``tensors`` runs the numba kernel.

    ``"numba"``: always (the caller converts to float32 CPU arrays); ``"torch"``: never; ``"auto"``: when
    every tensor is on the CPU, none needs a gradient (the kernels are not differentiable) and, with
    ``float32_only``, every tensor is float32 (kernels that compute in float32 and cast back pass False).
    """
    if backend not in BACKENDS:
        raise StereoInputError(f"backend: expected 'auto', 'torch' or 'numba', got {backend!r}")
    if backend != "auto":
        return backend == "numba"
    grad = torch.is_grad_enabled()
    return all(t.device.type == "cpu" and not (grad and t.requires_grad)
               and (not float32_only or t.dtype == torch.float32) for t in tensors)


def empty_array(shape: tuple[int, ...], dtype, zero: bool = False) -> np.ndarray:
    """A (zeroed with ``zero``) numpy array of ``shape`` and numpy ``dtype`` on torch's CPU allocator, for the
    large buffers the kernels fill.

    numpy marks every array of 4 MiB or more as ``MADV_HUGEPAGE``; under the common transparent-huge-page setting
    ``defrag=madvise`` the kernel then compacts memory *synchronously* on a first touch whenever free 2 MiB blocks
    are scarce, so a call's time depends on the machine's memory state: ``bp``'s first call on a KITTI pair spent
    0.6 s of system time in such faults (0.94 s against 0.38 s for the next calls). torch's allocator does not ask
    for huge pages: ordinary 4 KiB faults, the same every call.
    """
    torch_dtype = torch.from_numpy(np.empty(0, dtype=dtype)).dtype
    make = torch.zeros if zero else torch.empty
    return make(tuple(int(n) for n in shape), dtype=torch_dtype).numpy()
