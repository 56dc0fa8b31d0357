"""The one matcher registry: one name -> one callable with one signature.

``matcher(left, right, max_disp, **options) -> StereoOutput`` for classical, learned and OpenCV methods
alike, so eval.py and infer.py treat them the same way. The registered matchers live in this package, one
module per family, and are the only code that composes the stages of the data path (``stereonet.cost`` ->
``stereonet.aggregate`` -> ``stereonet.select``, ``stereonet.models``); no algorithm module imports the
registry. The family modules are imported the first time the registry is asked for a name:

=================================  =========================================================
``stereonet.matchers.opencv``      ``opencv-bm``, ``opencv-sgbm`` (baselines)
``stereonet.matchers.local``       ``bm-*`` (block matching), ``sgm``
``stereonet.matchers.energy``      ``dp``, ``bp``, ``graphcut`` (energy minimisation)
``stereonet.matchers.learned``     ``siamese``, ``siamese-sgm``, ``siamese-census-sgm``, ``dispnet``, ``smd``
=================================  =========================================================
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass

import torch

from stereonet.checks import StereoInputError, check_stereo_inputs, inputs_checked
from stereonet.types import StereoOutput

MatcherFn = Callable[..., StereoOutput]

# The family modules of this package, in registration order (see the table above).
_FAMILIES = ("opencv", "local", "energy", "learned")


@dataclass(frozen=True)
class MatcherSpec:
    name: str
    fn: MatcherFn
    kind: str  # "classical" | "learned" | "opencv"
    description: str
    needs_weights: bool = False


_REGISTRY: dict[str, MatcherSpec] = {}
_loaded = False


def register(name: str, *, kind: str, description: str, needs_weights: bool = False) -> Callable[[MatcherFn], MatcherFn]:
    """Decorator: register ``fn(left, right, max_disp, **options) -> StereoOutput`` under ``name``."""

    def deco(fn: MatcherFn) -> MatcherFn:
        if name in _REGISTRY and _REGISTRY[name].fn is not fn:
            raise StereoInputError(f"name: matcher {name!r} is already registered")
        _REGISTRY[name] = MatcherSpec(name, fn, kind, description, needs_weights)
        return fn

    return deco


def _load_providers() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for family in _FAMILIES:
        importlib.import_module(f"{__name__}.{family}")


def available(kind: str | None = None) -> list[str]:
    """Registered names (optionally of one ``kind``), in registration order."""
    _load_providers()
    return [n for n, s in _REGISTRY.items() if kind is None or s.kind == kind]


def spec(name: str) -> MatcherSpec:
    _load_providers()
    if name not in _REGISTRY:
        raise StereoInputError(f"method: unknown matcher {name!r}; valid names: {', '.join(available())}")
    return _REGISTRY[name]


def get_matcher(name: str, **options) -> MatcherFn:
    """The matcher called ``name`` with ``options`` bound; it checks its inputs before running."""
    s = spec(name)

    @functools.wraps(s.fn)
    def run(left: torch.Tensor, right: torch.Tensor, max_disp: int, **more) -> StereoOutput:
        left, right, max_disp = check_stereo_inputs(left, right, max_disp)
        with inputs_checked(left, right):  # checked once: the stages below skip the second pass over them
            return s.fn(left, right, max_disp, **{**options, **more})

    return run


def match(name: str, left: torch.Tensor, right: torch.Tensor, max_disp: int, **options) -> StereoOutput:
    """Run the matcher ``name`` once."""
    return get_matcher(name, **options)(left, right, max_disp)


def register_checkpoint_variant(entry: str) -> str:
    """``LABEL=METHOD@CHECKPOINT`` (or ``METHOD@CHECKPOINT``): register ``LABEL`` (default: the entry) as the
    learned matcher ``METHOD`` with other weights, for experiments and benchmarks; returns the name to run.
    Without a checkpoint the method's own name is returned."""
    label, sep, rest = entry.partition("=")
    method, _, checkpoint = (rest if sep else entry).partition("@")
    if not checkpoint:
        return method
    fn = get_matcher(method, checkpoint=checkpoint)
    if label not in _REGISTRY:
        register(label, kind="learned", description=f"{method} with {checkpoint}")(lambda l, r, m: fn(l, r, m))
    return label


def weights_available(name: str) -> bool:
    """Whether matcher ``name`` can run without an explicit checkpoint (always True when it needs none;
    for a learned matcher: whether the shipped weights of its network are installed)."""
    if not spec(name).needs_weights:
        return True
    from stereonet.matchers.learned import weights_available as learned_weights_available

    return learned_weights_available(name)
