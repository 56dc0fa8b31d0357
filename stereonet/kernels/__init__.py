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

import ctypes
import mmap

import numpy as np
import torch

from stereonet.checks import StereoInputError

BACKENDS = ("auto", "torch", "numba")


def use_numba(*tensors: torch.Tensor, backend: str = "auto", float32_only: bool = True) -> bool:
    """The one backend rule: whether a call with ``tensors`` runs the numba kernel.

    ``"numba"``: always (the caller converts to float32 CPU arrays); ``"torch"``: never; ``"auto"``: when
    every tensor is on the CPU, none needs a gradient (the kernels are not differentiable) and, with
    ``float32_only``, every tensor is float32 (kernels that compute in float32 and cast back pass False; they
    still take floating tensors in float32 or float64 only: half precision runs the torch reference).
    """
    if backend not in BACKENDS:
        raise StereoInputError(f"backend: expected 'auto', 'torch' or 'numba', got {backend!r}")
    if backend != "auto":
        return backend == "numba"
    grad = torch.is_grad_enabled()
    return all(t.device.type == "cpu" and not (grad and t.requires_grad)
               and (t.dtype == torch.float32 if float32_only else
                    t.dtype in (torch.float32, torch.float64) or not t.is_floating_point()) for t in tensors)


_MADV_NOHUGEPAGE = 15  # Linux (asm-generic/mman-common.h)
try:
    _madvise = ctypes.CDLL(None, use_errno=True).madvise  # the process's C library
    _madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
except (OSError, AttributeError):  # no dlopen(NULL) or no madvise: nothing to ask
    _madvise = None


def no_huge_pages(address: int, nbytes: int) -> bool:
    """Ask the kernel not to back the whole pages inside ``[address, address + nbytes)`` with transparent huge
    pages (``madvise(MADV_NOHUGEPAGE)``), before their first touch; True where applied (Linux), else False.

    The flag belongs to the memory mapping, and heap memory that numpy once marked ``MADV_HUGEPAGE`` keeps that
    mark for whatever later reuses it, so a buffer that must avoid huge pages says so itself."""
    if _madvise is None:
        return False
    lo = -(-address // mmap.PAGESIZE) * mmap.PAGESIZE
    hi = (address + nbytes) // mmap.PAGESIZE * mmap.PAGESIZE
    return hi > lo and _madvise(lo, hi - lo, _MADV_NOHUGEPAGE) == 0


def empty_array(shape: tuple[int, ...], dtype, zero: bool = False) -> np.ndarray:
    """A (zeroed with ``zero``) numpy array of ``shape`` and numpy ``dtype`` on torch's CPU allocator, without
    transparent huge pages, for the large buffers the kernels fill.

    numpy marks every array of 4 MiB or more as ``MADV_HUGEPAGE``; under the common transparent-huge-page setting
    ``defrag=madvise`` the kernel then compacts memory *synchronously* on a first touch whenever free 2 MiB blocks
    are scarce, so a call's time depends on the machine's memory state: ``bp``'s first call on a KITTI pair spent
    0.6 s of system time in such faults (0.94 s against 0.38 s for the next calls). torch's allocator does not ask
    for huge pages, but heap memory numpy once marked keeps the mark when torch reuses it (with
    :func:`stereonet.measure.reuse_freed_memory`, as in the programs), so a buffer of 4 MiB or more is also marked
    ``MADV_NOHUGEPAGE`` before it is first touched (:func:`no_huge_pages`): ordinary 4 KiB faults.
    """
    torch_dtype = torch.from_numpy(np.empty(0, dtype=dtype)).dtype
    out = torch.empty(tuple(int(n) for n in shape), dtype=torch_dtype).numpy()
    if out.nbytes >= 4 << 20:
        no_huge_pages(out.__array_interface__["data"][0], out.nbytes)
    if zero:
        out.fill(0)
    return out
