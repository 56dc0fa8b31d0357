"""One input-check helper family used by every public entry point.

Every failure raises :class:`StereoInputError` (a ``ValueError``) or ``TypeError`` with a message that names
the argument, what was expected and what was received (shapes and dtypes, never tensor values).
"""

from __future__ import annotations

import contextlib
import contextvars
import math
from collections.abc import Iterator, Sequence

import torch


class StereoInputError(ValueError):
    """Bad input to a public stereonet function; the message names the argument."""


class DegenerateGeometryError(StereoInputError):
    """The input is well-formed but geometrically degenerate (too few points, collinear or coplanar points,
    pure rotation, an epipole that cannot be sent to infinity...). The message says which case."""


def _shape(t: torch.Tensor) -> tuple[int, ...]:
    return tuple(int(s) for s in t.shape)


def check_tensor(x: object, name: str) -> torch.Tensor:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor, got {type(x).__name__}")
    return x


def check_shape(x: torch.Tensor, dims: Sequence[str], name: str) -> dict[str, int]:
    """Check ``x`` against symbolic ``dims`` like ``["B", "3", "H", "W"]`` (``"*"`` = any leading dims).

    Digits must match exactly; letters bind to sizes (the same letter must bind to the same size).
    Returns the bindings, e.g. ``{"B": 2, "H": 64, "W": 128}``.
    """
    check_tensor(x, name)
    shape = _shape(x)
    dims = list(dims)
    expected = "(" + ", ".join(dims) + ")"
    if dims and dims[0] == "*":
        dims = dims[1:]
        if len(shape) < len(dims):
            raise StereoInputError(f"{name}: expected shape {expected}, got {shape}")
        shape = shape[len(shape) - len(dims):]
    elif len(shape) != len(dims):
        raise StereoInputError(f"{name}: expected shape {expected}, got {_shape(x)}")
    bound: dict[str, int] = {}
    for d, s in zip(dims, shape):
        if d.isdigit():
            if int(d) != s:
                raise StereoInputError(f"{name}: expected shape {expected}, got {_shape(x)}")
        else:
            if d in bound and bound[d] != s:
                raise StereoInputError(f"{name}: expected shape {expected} with equal '{d}' sizes, got {_shape(x)}")
            bound[d] = s
    return bound


# Tensors a caller has already checked (the matcher registry checks every pair once, then runs the matcher
# inside :func:`inputs_checked`): check_finite, the one full pass over the data, skips these very objects,
# so the algorithms keep calling the public, checking functions without a second pass over the images.
_CHECKED: contextvars.ContextVar[tuple] = contextvars.ContextVar("stereonet_checked_inputs", default=())


@contextlib.contextmanager
def inputs_checked(*tensors: torch.Tensor) -> Iterator[None]:
    """Within the block, :func:`check_finite` trusts these tensor objects (identity, not value: a new tensor
    made from them is checked again). Only for tensors that went through the same checks just before."""
    token = _CHECKED.set(_CHECKED.get() + tensors)
    try:
        yield
    finally:
        _CHECKED.reset(token)


def check_number(value: object, name: str, minimum: float | None = 0.0, strict: bool = False,
                 allow_inf: bool = False) -> float:
    """A real number option (numpy scalars included; not a bool or a string), finite unless ``allow_inf``, and
    ``>= minimum`` (``> minimum`` with ``strict``; None = no bound), as float. NaN fails: it would silently switch
    a comparison-based check off or make it reject everything."""
    try:
        number = math.nan if isinstance(value, bool | str) else float(value)
    except (TypeError, ValueError):
        number = math.nan
    low = minimum is not None and (number <= minimum if strict else number < minimum)
    if math.isnan(number) or (math.isinf(number) and not allow_inf) or low:
        bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"
        raise StereoInputError(f"{name}: expected a {'' if allow_inf else 'finite '}number{bound}, got {value!r}")
    return number


def check_finite(x: torch.Tensor, name: str) -> None:
    if any(x is t for t in _CHECKED.get()):
        return
    # the sum is finite iff every value is, unless finite values overflow it: only then the elementwise test
    # (one reduction instead of a bool tensor the size of the image: ~30x faster on a Cones-sized image)
    if x.is_floating_point() and not bool(torch.isfinite(x.sum())) and not bool(torch.isfinite(x).all()):
        raise StereoInputError(f"{name}: expected finite values, got NaN or inf")


def check_image(x: object, name: str = "image", channels: Sequence[int] = (1, 3)) -> torch.Tensor:
    """Check a float image batch :math:`(B, C, H, W)`, C in ``channels``, finite, non-empty."""
    x = check_tensor(x, name)
    if x.dim() != 4:
        raise StereoInputError(f"{name}: expected shape (B, C, H, W), got {_shape(x)}")
    if not x.is_floating_point():
        raise TypeError(f"{name}: expected a floating-point image in [0, 1], got dtype {x.dtype}")
    b, c, h, w = _shape(x)
    if b == 0 or h == 0 or w == 0:
        raise StereoInputError(f"{name}: expected a non-empty image, got shape {_shape(x)}")
    if c not in channels:
        raise StereoInputError(f"{name}: expected {' or '.join(map(str, channels))} channels, got {c} (shape {_shape(x)})")
    check_finite(x, name)
    return x


EIGHT_BIT_GUARD = 2.0
"""A stereo pair (:func:`check_image_pair`, the matchers' entry) whose maximum exceeds this is taken for unscaled
8/16-bit values (the matchers' thresholds, census aside, assume [0, 1]); slight overshoots, e.g. after augmentation
or resampling, pass. Single images inside the pipeline (standardised ones included) are not held to it."""


def check_image_pair(left: object, right: object, channels: Sequence[int] = (1, 3)) -> tuple[torch.Tensor, torch.Tensor]:
    """Check a stereo pair: both valid images of the same shape, dtype and device."""
    left = check_image(left, "left", channels)
    right = check_image(right, "right", channels)
    for name, x in (("left", left), ("right", right)):  # what a user passes in: images in [0, 1]
        if any(x is t for t in _CHECKED.get()):  # a matcher inside a matcher: checked once, at the entry
            continue
        top = float(x.detach().amax())
        if top > EIGHT_BIT_GUARD:
            raise StereoInputError(f"{name}: expected values in [0, 1], got a maximum of {top:g} "
                                   "(8- or 16-bit values? divide by 255 or 65535)")
    if left.shape != right.shape:
        raise StereoInputError(f"right: expected the same shape as left {_shape(left)}, got {_shape(right)}")
    if left.dtype != right.dtype:
        raise TypeError(f"right: expected the same dtype as left ({left.dtype}), got {right.dtype}")
    if left.device != right.device:
        raise StereoInputError(f"right: expected the same device as left ({left.device}), got {right.device}")
    return left, right


def check_max_disp(max_disp: object, width: int, name: str = "max_disp") -> int:
    """Check a disparity range: an integer with ``0 < max_disp < width``."""
    if isinstance(max_disp, bool) or not isinstance(max_disp, int | float) or not math.isfinite(max_disp) \
            or int(max_disp) != max_disp:
        raise TypeError(f"{name}: expected a positive integer, got {max_disp!r}")
    max_disp = int(max_disp)
    if max_disp <= 0 or max_disp >= width:
        raise StereoInputError(f"{name}: expected 0 < {name} < image width ({width}), got {max_disp}")
    return max_disp


def check_window(size: object, name: str = "window") -> int:
    """Check an odd positive window size."""
    if isinstance(size, bool) or not isinstance(size, int) or size <= 0 or size % 2 == 0:
        raise StereoInputError(f"{name}: expected an odd positive integer, got {size!r}")
    return size


def check_stereo_inputs(left: object, right: object, max_disp: object,
                        channels: Sequence[int] = (1, 3)) -> tuple[torch.Tensor, torch.Tensor, int]:
    """The check every matcher runs first: a valid pair and ``0 < max_disp < W``."""
    left, right = check_image_pair(left, right, channels)
    return left, right, check_max_disp(max_disp, left.shape[-1])


def check_cost_volume(cost: object, name: str = "cost") -> torch.Tensor:
    cost = check_tensor(cost, name)
    check_shape(cost, ["B", "D", "H", "W"], name)
    if not cost.is_floating_point():
        raise TypeError(f"{name}: expected a floating-point cost volume, got {cost.dtype}")
    if cost.shape[1] == 0:
        raise StereoInputError(f"{name}: expected at least one disparity level, got shape {_shape(cost)}")
    return cost
