"""The matcher registry: one name -> one callable with one signature.

``matcher(left, right, max_disp, **options) -> StereoOutput`` for classical, learned and OpenCV methods
alike, so eval.py and infer.py treat them the same way. Providers register themselves when imported; the
registry imports every provider module listed in ``_PROVIDERS`` the first time it is asked for a name.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass

import torch

from stereonet.checks import StereoInputError, check_stereo_inputs
from stereonet.types import StereoOutput

MatcherFn = Callable[..., StereoOutput]

# Modules that register matchers when imported, one per family (each owned by its family's package).
_PROVIDERS = (
    "stereonet.baselines",          # opencv-bm, opencv-sgbm
    "stereonet.optimize.registered_local",   # bm-*, sgm
    "stereonet.optimize.registered_global",  # dp, bp, graphcut
    "stereonet.models.registered",    # siamese, siamese-sgm, dispnet, smd
)


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
    for mod in _PROVIDERS:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as e:  # a family not built yet: its names are simply absent
            if e.name != mod and not mod.startswith(str(e.name)):
                raise


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
        return s.fn(left, right, max_disp, **{**options, **more})

    return run


def match(name: str, left: torch.Tensor, right: torch.Tensor, max_disp: int, **options) -> StereoOutput:
    """Run the matcher ``name`` once."""
    return get_matcher(name, **options)(left, right, max_disp)


def weights_available(name: str) -> bool:
    """Whether matcher ``name`` can run without an explicit checkpoint (always True when it needs none).

    Asks ``stereonet.models.registered.weights_available`` when the learned family provides it, else looks
    for the shipped file of the matcher's network (``siamese-sgm`` uses ``siamese``'s weights).
    """
    if not spec(name).needs_weights:
        return True
    try:
        from stereonet.models import registered
        from stereonet.models.weights import default_weights_path
    except ImportError:
        return False
    probe = getattr(registered, "weights_available", None)
    if probe is not None:
        try:
            return bool(probe(name))
        except (KeyError, ValueError):  # a name the learned family does not know: look for the file
            pass
    return default_weights_path(name.split("-")[0]).is_file()
