"""Learned matchers in the registry: ``siamese``, ``siamese-sgm``, ``siamese-census-sgm``, ``dispnet``, ``smd``,
``sgm-refine``, ``sgm-penalties``.

Each loads its network from ``stereonet/weights/<name>.pt`` (or ``.ckpt``) the first time it runs (cached per file);
``checkpoint=PATH`` overrides. Missing files, checkpoints of another model and tensors of the wrong shape
raise errors that name the file (see :mod:`stereonet.models.weights`). No Lightning import here.

Backends: ``backend="torch"`` (default) runs the network in torch; ``backend="onnx"`` runs its ONNX export
in onnxruntime on the CPU, from ``onnx_model=PATH`` (written by ``python -m stereonet.export onnx``) or, without
one, exported in memory from the weights the first time (cached per file; nothing is written or downloaded).
Only the network's forward pass is swapped (:func:`network_graph`, the graphs of :mod:`stereonet.models.graphs`):
the rest of each matcher is the same code for both backends.

Disparities beyond the trained range: DispNet and SMD correlate up to the ``max_disp`` they were trained
with (``net.max_disp``, stored in the weights file; 96 px for the shipped ones). When the requested
``max_disp`` is larger, the pair is downscaled by ``trained / max_disp`` before the network runs and the
disparity is upscaled back (so KITTI at full width, ~200 px, runs at about half its size). The
Siamese matchers have no such limit (the cost volume spans ``max_disp``).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import torch
import torch.nn.functional as F

from stereonet.checks import StereoInputError, check_number
from stereonet.matchers import register
from stereonet.models.dispnet import run_padded
from stereonet.models.graphs import NetworkGraph, OnnxGraph
from stereonet.models.layers import InputPadder, resize_disparity
from stereonet.models.siamese import siamese_cost_volume, tower_dtype
from stereonet.models.smd import MixtureParams, error_probability, mixture_outputs, padded_query_grid
from stereonet.models.weights import default_weights_path, load_weights
from stereonet.select.fill import fill_occlusions
from stereonet.select.filters import (
    WMF_RADIUS,
    WMF_SIGMA_COLOR,
    WMF_STRIDE,
    check_wmf_options,
    filled_weighted_median,
    weighted_median_filter,
)
from stereonet.select.lr_check import LR_TOL, left_right_check
from stereonet.types import StereoOutput

BACKENDS = ("torch", "onnx")


@functools.lru_cache(maxsize=8)
def _cached(path: str, mtime: float, expected: str):
    return load_weights(path, expected)[0]


NETWORK_OF = {"dispnet": "dispnet", "smd": "smd", "siamese": "siamese", "siamese-sgm": "siamese",
              "siamese-census-sgm": "siamese", "sgm-refine": "refine", "sgm-penalties": "penalty"}


def weights_available(name: str) -> bool:
    """Whether the shipped weights of learned matcher ``name`` exist (a name registered elsewhere, e.g.
    ``siamese-foo``: the weights of the network its name starts with)."""
    return default_weights_path(NETWORK_OF.get(name, name.split("-")[0])).is_file()


def load_network(expected: str, checkpoint: str | os.PathLike | None = None) -> torch.nn.Module:
    """The network for matcher family ``expected`` from ``checkpoint`` or the shipped weights (cached)."""
    path = Path(checkpoint) if checkpoint is not None else default_weights_path(expected)
    mtime = path.stat().st_mtime if path.is_file() else -1.0
    if mtime < 0:
        load_weights(path, expected)  # raises the FileNotFoundError with the message
    return _cached(str(path), mtime, expected)


@functools.lru_cache(maxsize=8)
def check_trained_on(path: str, mtime: float) -> str | None:
    """The warning for the weights file at ``path`` when it records (``trained_on``) the digest
    (:func:`~stereonet.models.weights.weights_digest`) of other shipped weights whose outputs it was trained on and
    the installed ones differ (e.g. ``refine.pt`` after ``siamese.pt`` was retrained); None when they match or it
    records nothing. Warned once per file (cached)."""
    import warnings

    from stereonet.models.weights import weights_digest

    info = load_weights(path)[1]
    for network, digest in (info.get("trained_on") or {}).items():
        installed = default_weights_path(network)
        if installed.is_file() and weights_digest(installed) != digest:
            message = (f"{Path(path).name} was trained on the outputs of another {network} weights file than the "
                       f"installed {installed} (weights digest {digest[:12]}...); its results may be worse: retrain it on "
                       f"the installed one")
            warnings.warn(message, stacklevel=3)
            return message
    return None


@functools.lru_cache(maxsize=8)
def _torch_graph(network: str, net: torch.nn.Module) -> NetworkGraph:
    """One graph per loaded network, so its per-device copies (NetworkGraph._net_on) are made once."""
    return NetworkGraph(network, net)


def methods_of(network: str) -> list[str]:
    """The registered matchers that run ``network`` ("siamese" -> siamese, siamese-sgm, siamese-census-sgm)."""
    return [m for m, n in NETWORK_OF.items() if n == network]


def _file_key(path: str | os.PathLike) -> tuple[str, float]:
    path = Path(path)
    return str(path), (path.stat().st_mtime if path.is_file() else -1.0)


@functools.lru_cache(maxsize=8)
def _onnx_file(path: str, mtime: float) -> OnnxGraph:
    return OnnxGraph(path)


@functools.lru_cache(maxsize=8)
def _onnx_in_memory(path: str, mtime: float, network: str) -> OnnxGraph:
    from stereonet.models.graphs import export_graph

    net, info = load_weights(path, network)
    exported = export_graph(network, net, dict(info["config"]), methods_of(network), weights=path)
    return OnnxGraph(exported.model, name=f"<{network} exported in memory from {path}>")


def network_graph(network: str, checkpoint: str | os.PathLike | None = None, backend: str = "torch",
                  onnx_model: str | os.PathLike | None = None) -> NetworkGraph | OnnxGraph:
    """The network part of the matchers of ``network`` ("siamese", "dispnet", "smd"), on ``backend``.

    ``"torch"``: the network from ``checkpoint`` or the shipped weights. ``"onnx"``: ``onnx_model`` run by
    onnxruntime, or without it the same weights exported in memory (once per file). Both are called alike
    (:mod:`stereonet.models.graphs`) and carry ``network``, ``max_disp``, ``stride`` and ``dtype``.
    """
    if backend not in BACKENDS:
        raise StereoInputError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    if backend == "torch":
        if onnx_model is not None:
            raise StereoInputError("onnx_model: only used with backend='onnx'")
        return _torch_graph(network, load_network(network, checkpoint))
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        raise ImportError("backend: 'onnx' needs onnxruntime and onnx (pip install 'stereonet[onnx]')") from None
    if onnx_model is not None:
        if checkpoint is not None:
            raise StereoInputError("checkpoint: an ONNX model carries its own weights; pass checkpoint or "
                                   "onnx_model, not both")
        key = _file_key(onnx_model)
        if key[1] < 0:
            raise FileNotFoundError(f"onnx_model: no such file: {onnx_model}")
        graph = _onnx_file(*key)
    else:
        path = Path(checkpoint) if checkpoint is not None else default_weights_path(network)
        key = _file_key(path)
        if key[1] < 0:
            load_weights(path, network)  # raises the FileNotFoundError with the message
        graph = _onnx_in_memory(*key, network)
    if graph.network != network:
        raise StereoInputError(f"onnx_model: {graph.name} holds a {graph.network!r} network, not the "
                               f"{network!r} one of {', '.join(methods_of(network))}")
    return graph


def _downscale_to_range(left: torch.Tensor, right: torch.Tensor, max_disp: int, trained_disp: int):
    """Downscale the pair by ``trained_disp / max_disp`` when ``max_disp`` exceeds the trained range.

    Returns (left, right, scale) with scale <= 1 (1 = unchanged); images :math:`(B, C, h, w)`.
    """
    scale = min(1.0, trained_disp / max_disp)
    if scale < 1.0:
        h, w = left.shape[-2:]
        size = (max(16, round(h * scale)), max(16, round(w * scale)))
        left = F.interpolate(left, size=size, mode="area")
        right = F.interpolate(right, size=size, mode="area")
    return left, right, scale


def _dispnet_predict(graph: NetworkGraph | OnnxGraph, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
    """DispNet disparity :math:`(B, 1, H, W)` of a pair of any size (padded to the stride, then unpadded)."""
    (disp,), padder = run_padded(graph, left.to(graph.dtype), right.to(graph.dtype))
    return padder.unpad(disp)


def _smd_predict(graph: NetworkGraph | OnnxGraph, left: torch.Tensor, right: torch.Tensor, upsample: float):
    """:func:`stereonet.models.smd.predict_smd` (``with_mixture=True``) on ``graph``."""
    left, right = left.to(graph.dtype), right.to(graph.dtype)
    b, _, h, w = left.shape
    padder = InputPadder(h, w, graph.stride)
    left_p, right_p = padder.pad(left, right)
    grid = padded_query_grid(b, h, w, padder, upsample, device=left.device, dtype=left.dtype)
    with torch.no_grad():
        mix = MixtureParams(*graph(left_p, right_p, grid))
    return mixture_outputs(mix, grid.shape[2] / w, with_mixture=True)


@register("dispnet", kind="learned", needs_weights=True,
          description="DispNet-style correlation U-Net trained on data_gen (weights/dispnet.pt) + a left-right check "
                      "+ an image-guided weighted median")
def dispnet_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint: str | None = None,
                    backend: str = "torch", onnx_model: str | None = None, lr_check: bool = True,
                    wmf_radius: int = WMF_RADIUS, wmf_sigma_color: float = WMF_SIGMA_COLOR,
                    wmf_stride: int = WMF_STRIDE) -> StereoOutput:
    """DispNet prediction :math:`(B, 1, H, W)`, clamped to [0, max_disp]. With ``lr_check`` (the default since the
    thirty-fifth session, by a data_gen rule: docs/experiments/dispnet_lr.txt) the network also runs on the
    mirrored, swapped pair (its left-referenced answer there, mirrored back, is the right view's map) and the
    pixels whose two answers disagree by more than the project's one left-right rule allows
    (:func:`~stereonet.select.lr_check.left_right_check` at its default 1 px, as ``sgm``'s) are rejected
    (occlusions and mismatches). Then, with ``wmf_radius`` > 0 (9 by default since the thirty-seventh session, by a
    data_gen rule: docs/experiments/dispnet_wmf.txt; 0 = off), the rejected pixels are filled by the shared rule
    (:func:`~stereonet.select.fill.fill_occlusions`, as ``eval.py --fill``) and the map goes through the
    image-guided weighted median (:func:`~stereonet.select.filters.weighted_median_filter`, radius ``wmf_radius``,
    ``wmf_sigma_color``, votes every ``wmf_stride`` px capped at the radius; ``sgm-refine``'s filter) against
    foreground fattening: every pixel valid, ``extras["lr_consistent"]`` the check's validity and
    ``extras["unfiltered"]`` the network's map. With ``wmf_radius=0`` the rejected pixels are invalid (``--fill``
    fills them); without the check and the filter every pixel is valid and the disparity is the network's."""
    if not isinstance(lr_check, bool):
        raise StereoInputError(f"lr_check: expected True or False, got {lr_check!r}")
    check_wmf_options(wmf_radius, wmf_sigma_color, wmf_stride)
    graph = network_graph("dispnet", checkpoint, backend, onnx_model)
    h, w = left.shape[-2:]
    small_left, small_right, _ = _downscale_to_range(left, right, max_disp, graph.max_disp)

    def predict(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            disp = _dispnet_predict(graph, first, second)
        if disp.shape[-2:] != (h, w):
            disp = resize_disparity(disp, h, w)
        return disp.clamp(0, max_disp).to(left.dtype)

    disp = predict(small_left, small_right)
    valid = torch.ones_like(disp, dtype=torch.bool)
    if lr_check:
        disp_right = predict(small_right.flip(-1), small_left.flip(-1)).flip(-1)
        valid = left_right_check(disp, disp_right)
    if not wmf_radius:
        return StereoOutput(disp, valid)
    filtered = filled_weighted_median(disp, valid, left, wmf_radius, wmf_sigma_color, wmf_stride)
    return StereoOutput(filtered, torch.ones_like(valid), extras={"lr_consistent": valid, "unfiltered": disp})


SMD_ERROR_TAU = 2.0
"""``smd``'s uncertainty is the mixture's probability of an error above this many pixels (bad-2's threshold)."""


@register("smd", kind="learned", needs_weights=True,
          description="SMD-Nets-style bimodal Laplacian head on DispNet: sharp edges + uncertainty (weights/smd.pt) "
                      "+ a left-right check + an image-guided weighted median")
def smd_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint: str | None = None,
                upsample: float = 1.0, backend: str = "torch", onnx_model: str | None = None,
                lr_check: bool = True, lr_uncertainty: str = "fill", wmf_radius: int = WMF_RADIUS,
                wmf_sigma_color: float = WMF_SIGMA_COLOR, wmf_stride: int = WMF_STRIDE) -> StereoOutput:
    """Mode of the mixture on a grid of ``upsample`` times the input size (default 1, values in pixels of
    that grid), clamped to [0, max_disp * upsample]; ``uncertainty`` = the probability under the predicted
    mixture that this answer is off by more than 2 px of that grid
    (:func:`~stereonet.models.smd.error_probability`; it ranks the head's errors better than the chosen mode's
    scale b on data_gen, docs/experiments/smd_uncertainty.txt), ``confidence = 1 - uncertainty``; extras hold
    both modes and the mixture weight. With ``lr_check`` (the default since the thirty-sixth session, by a data_gen
    rule: docs/experiments/smd_lr.txt) the network also runs on the mirrored, swapped pair, as ``dispnet``'s check:
    pixels whose two answers differ by more than the one left-right rule's tolerance (in input pixels, so
    ``upsample`` times it on the output grid) are invalid (``--fill`` answers them); the disparity and the other
    pixels' uncertainty are unchanged. A rejected pixel's uncertainty (``lr_uncertainty``): ``"fill"`` (default)
    the mixture's probability that the shared fill's answer there
    (:func:`~stereonet.select.fill.fill_occlusions`, what ``--fill`` outputs) is off by more than 2 px, so the
    uncertainty describes the answer that is output; ``"one"`` uncertainty 1 (confidence 0, as ``sgm`` scores its
    rejected pixels; negative on data_gen, docs/experiments/smd_lr.txt). With ``wmf_radius`` > 0 (9 by default
    since the thirty-seventh session, by a data_gen rule: docs/experiments/smd_wmf.txt; 0 = off) the mode, its
    rejected pixels filled by the shared rule, then goes through
    ``dispnet``'s image-guided weighted median (:func:`~stereonet.select.filters.weighted_median_filter`; radius,
    stride and the 1 px step that marks a discontinuity in input pixels, so ``upsample`` times them on the output
    grid, guided by the left image resized bilinearly to that grid): every pixel valid, the uncertainty the
    mixture's probability that the filtered answer is off by more than 2 px (1 at rejected pixels with
    ``lr_uncertainty="one"``), ``extras["lr_consistent"]`` the check's validity, ``extras["unfiltered"]`` the mode."""
    if not isinstance(lr_check, bool):
        raise StereoInputError(f"lr_check: expected True or False, got {lr_check!r}")
    if lr_uncertainty not in ("fill", "one"):
        raise StereoInputError(f"lr_uncertainty: expected 'fill' or 'one', got {lr_uncertainty!r}")
    check_number(upsample, "upsample", strict=True)  # the output grid's scale (1 = the input grid)
    check_wmf_options(wmf_radius, wmf_sigma_color, wmf_stride)
    graph = network_graph("smd", checkpoint, backend, onnx_model)
    h, w = left.shape[-2:]
    hq, wq = round(h * upsample), round(w * upsample)
    small_left, small_right, scale = _downscale_to_range(left, right, max_disp, graph.max_disp)

    def predict(first: torch.Tensor, second: torch.Tensor) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        disp, _, mix = _smd_predict(graph, first, second, upsample / scale)
        if disp.shape[-2:] != (hq, wq):  # rounding of the downscaled size
            ratio = wq / disp.shape[-1]
            disp = resize_disparity(disp, hq, wq, mode="nearest")
            mix = {k: F.interpolate(v, size=(hq, wq), mode="nearest") * (1.0 if k == "pi" else ratio)
                   for k, v in mix.items()}
        return disp.clamp(0, max_disp * upsample), mix

    disp, mix = predict(small_left, small_right)
    params = MixtureParams(**mix)
    valid = torch.ones_like(disp, dtype=torch.bool)
    extras = {k: v.to(left.dtype) for k, v in mix.items()}
    if lr_check:
        disp_right = predict(small_right.flip(-1), small_left.flip(-1))[0].flip(-1)
        valid = left_right_check(disp, disp_right, LR_TOL * upsample)
    answer = fill_occlusions(disp, valid) if lr_check else disp  # what --fill outputs (the mode where accepted)
    if wmf_radius:
        radius = max(1, round(wmf_radius * upsample))  # input pixels -> the output grid's
        guide = left if (hq, wq) == (h, w) else F.interpolate(left, size=(hq, wq), mode="bilinear",
                                                               align_corners=False)
        answer = weighted_median_filter(answer, guide.to(disp.dtype), radius=radius, sigma_color=wmf_sigma_color,
                                        stride=min(max(1, round(wmf_stride * upsample)), radius), jump=upsample)
        extras.update(lr_consistent=valid, unfiltered=disp.to(left.dtype))
    unc = error_probability(params, answer, SMD_ERROR_TAU)  # the answer that is output is off by more than 2 px
    if lr_uncertainty == "one":
        unc = torch.where(valid, unc, torch.ones_like(unc))
    if wmf_radius:
        disp, valid = answer, torch.ones_like(valid)
    return StereoOutput(disp.to(left.dtype), valid, uncertainty=unc.to(left.dtype),
                        confidence=(1.0 - unc).to(left.dtype), extras=extras)


def _siamese_cost(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint, backend: str = "torch",
                  onnx_model: str | None = None, precision: str = "float32") -> torch.Tensor:
    """The Siamese cost volume; ``precision`` (:data:`stereonet.models.siamese.PRECISIONS`) sets the tower's
    arithmetic on the torch backend (see ``tower_dtype``)."""
    dtype = tower_dtype(precision, left.device)
    graph = network_graph("siamese", checkpoint, backend, onnx_model)
    if isinstance(graph, OnnxGraph):
        if precision == "bfloat16":
            raise StereoInputError("precision: 'bfloat16' runs on backend='torch' only (the ONNX graph is float32)")
        run = graph
    else:
        run = functools.partial(graph.features, dtype=dtype)
    with torch.no_grad():
        (feats,) = run(torch.cat([left, right]).to(graph.dtype))  # 2BxFxHxW
        b = left.shape[0]
        return siamese_cost_volume(feats[:b], feats[b:], max_disp).to(left.dtype)


@register("siamese", kind="learned", needs_weights=True,
          description="MC-CNN-fast-style Siamese features, dot-product cost, winner-takes-all + subpixel")
def siamese_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint: str | None = None,
                    backend: str = "torch", onnx_model: str | None = None, precision: str = "float32") -> StereoOutput:
    """WTA on the learned cost volume with parabola sub-pixel refinement; every pixel valid. ``precision``:
    the feature tower's arithmetic, ``"float32"`` (default), ``"bfloat16"`` (all convolutions but the first;
    ~1.7x faster on a CPU with native bfloat16, unit features within ~5e-3, but data_gen validation bad-2 a
    little worse: opt-in, see the model card) or ``"auto"`` (bfloat16 where the CPU has it natively)."""
    from stereonet.select.subpixel import subpixel_refine
    from stereonet.select.wta import wta

    cost = _siamese_cost(left, right, max_disp, checkpoint, backend, onnx_model, precision)
    disp, min_cost = wta(cost)
    disp = subpixel_refine(cost, disp)
    return StereoOutput(disp, torch.ones_like(disp, dtype=torch.bool), cost_volume=cost,
                        confidence=(1.0 - min_cost / 2.0).clamp(0, 1))


@register("siamese-sgm", kind="learned", needs_weights=True,
          description="Siamese learned cost + SGM (8 paths) + LR check + occlusion filling")
def siamese_sgm_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint: str | None = None,
                        P1: float = 0.05, P2: float = 0.6, p2_alpha: float = 0.0, paths: int = 8,
                        disp12_max_diff: float = 1.0, fill: bool = True, backend: str = "torch",
                        onnx_model: str | None = None, precision: str = "float32") -> StereoOutput:
    """SGM on the Siamese cost (``1 - cos`` in [0, 2]; P1/P2 in those units), WTA + parabola sub-pixel,
    left-right check (tolerance ``disp12_max_diff`` px, OpenCV's name) and, with ``fill``, textbook occlusion filling (then every pixel
    is valid; ``extras["lr_consistent"]`` keeps the check). Without ``fill``, ``valid`` = the LR check.
    ``confidence``: the aggregated cost's margin (:mod:`stereonet.select.confidence`), 0 where the LR
    check failed. ``precision``: as for ``siamese``."""
    from stereonet.aggregate.sgm import sgm_aggregate
    from stereonet.select.confidence import cost_margin_confidence
    from stereonet.select.fill import fill_occlusions
    from stereonet.select.lr_check import wta_right
    from stereonet.select.subpixel import subpixel_refine
    from stereonet.select.wta import wta

    cost = _siamese_cost(left, right, max_disp, checkpoint, backend, onnx_model, precision)
    agg = sgm_aggregate(cost, P1, P2, paths=paths, image=left if p2_alpha else None, p2_alpha=p2_alpha)
    disp_int, _ = wta(agg)
    disp = subpixel_refine(agg, disp_int)
    consistent = left_right_check(disp_int, wta_right(agg), tol=disp12_max_diff)
    if fill:
        disp = fill_occlusions(disp, consistent)
        valid = torch.ones_like(consistent)
    else:
        valid = consistent
    confidence = cost_margin_confidence(agg) * consistent.to(agg.dtype)  # 0 where the LR check failed
    return StereoOutput(disp, valid, confidence=confidence, cost_volume=agg, extras={"lr_consistent": consistent})


# Weight of the learned cost in siamese-census-sgm, chosen on data_gen validation pairs only for the shipped
# weights (0.75 for the fifth-session weights, 0.9 for the far-negatives ones, and 0.9 again for the fourteenth
# session's five-layer ones; see the model card)
LEARNED_WEIGHT = 0.9


def census_mix_weights(learned_weight: float) -> tuple[float, float]:
    """``(w_census, w_learned)`` of siamese-census-sgm's cost ``w_census * census + w_learned * (1 - cos)``:
    ``(1 - a, 24 a)``, the Siamese cost (0..2) brought to the census's 0..48 bits."""
    return 1.0 - learned_weight, 24.0 * learned_weight


@register("siamese-census-sgm", kind="learned", needs_weights=True,
          description="sgm on census 7x7 + the Siamese learned cost (weights/siamese.pt), sgm's back end")
def siamese_census_sgm_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint: str | None = None,
                               learned_weight: float = LEARNED_WEIGHT, backend: str = "torch",
                               onnx_model: str | None = None, precision: str = "float32", **options) -> StereoOutput:
    """``sgm`` (same penalties, selection, filters and confidence; options as for ``sgm``) on the cost
    ``(1 - a) * census + a * 24 * (1 - cos)``: the census Hamming distance (0..48 bits) and the Siamese
    cost (0..2) brought to the same range, ``a = learned_weight`` (0 = plain ``sgm``), rounded to quarter bits
    (``mix_step``, see ``sgm``) so that the CPU aggregates it in 16 bits like plain ``sgm``. ``precision``: as
    for ``siamese``."""
    from stereonet.matchers.local import sgm

    if not 0.0 <= learned_weight <= 1.0:
        raise StereoInputError(f"learned_weight: expected a value in [0, 1], got {learned_weight!r}")
    learned = _siamese_cost(left, right, max_disp, checkpoint, backend, onnx_model, precision).clamp_(max=2.0)  # BxDxHxW, ours
    return sgm(left, right, max_disp, extra_cost=(*census_mix_weights(learned_weight), learned), **options)


def sgm_base(left: torch.Tensor, right: torch.Tensor, max_disp: int, **sgm_options):
    """What ``sgm-refine``'s network reads, for training and inference alike: ``sgm``'s disparity with the
    invalid pixels filled by the shared rule (:func:`~stereonet.select.fill.fill_occlusions`, as
    ``eval.py --fill`` fills every method), its validity and its cost-margin confidence (0 where invalid)."""
    return refine_bases(("sgm",), left, right, max_disp, **sgm_options)


def refine_bases(bases, left: torch.Tensor, right: torch.Tensor, max_disp: int, cross: bool = False,
                 wmf: tuple[int, float] | None = None, wmf_bases: tuple[str, ...] | None = None,
                 prefilter: str | None = None, **sgm_options):
    """The maps of the matchers ``bases`` (:data:`stereonet.models.refine.BASES`) as a RefineNet reads them:
    each filled by the shared rule, stacked along the channels as ``(disparity, valid, confidence)``, each
    :math:`(B, M, H, W)`. ``sgm_options`` go to ``sgm``; the Siamese matchers run with the shipped weights.
    ``cross``: the SGM-family bases (:data:`~stereonet.models.refine.CROSS_BASES`) also keep their 16-bit
    aggregated costs, and a fourth tensor, :func:`~stereonet.models.refine.cross_costs` :math:`(B, M M, H, W)`,
    says how each base's cost rates each base's filled map (``evidence="cross"`` networks). ``wmf=(radius,
    sigma_color)``: each filled map then goes through the image-guided weighted median
    (:func:`~stereonet.select.filters.weighted_median_filter`) before it is stacked (validity and confidence as before;
    the cross costs rate the unfiltered maps); ``wmf_bases``: only the maps of these bases (None: every one).
    ``prefilter``: the census cost of the SGM-family bases (:data:`~stereonet.models.refine.CROSS_BASES`) reads
    pre-filtered images (``sgm``'s option of that name); the Siamese tower reads the images as they are."""
    from stereonet.matchers import get_matcher
    from stereonet.models.refine import BASES, CROSS_BASES, cross_costs
    from stereonet.select.fill import fill_occlusions

    maps, valids, confidences, aggregates = [], [], [], []
    for name in bases:
        if name not in BASES:
            raise StereoInputError(f"bases: unknown base matcher {name!r}; expected one of {', '.join(BASES)}")
        if cross and name not in CROSS_BASES:
            raise StereoInputError(f"bases: cross costs need SGM-family bases ({', '.join(CROSS_BASES)}), got {name!r}")
        options = dict(sgm_options if name == "sgm" else {}, **({"keep_volume": "fixed"} if cross else {}),
                       **({"prefilter": prefilter} if prefilter is not None and name in CROSS_BASES else {}))
        out = get_matcher(name, **options)(left, right, max_disp)
        confidence = out.confidence if out.confidence is not None else out.valid.to(left.dtype)
        maps.append(fill_occlusions(out.disparity, out.valid))
        valids.append(out.valid)
        confidences.append(confidence)
        if cross:
            volume = out.extras.get("aggregate_fixed")
            if volume is None:  # only the CPU's 16-bit path keeps the int16 aggregate; elsewhere the float32 one
                aggregates.append((out.cost_volume, 1.0))
            else:
                aggregates.append((volume, float(out.extras["aggregate_scale"])))
    result = torch.cat(maps, 1), torch.cat(valids, 1), torch.cat(confidences, 1)
    costs = (cross_costs(aggregates, result[0]),) if cross else ()
    if wmf is not None:
        radius, sigma_color = wmf
        filtered = [weighted_median_filter(m, left, radius=radius, sigma_color=sigma_color)
                    if wmf_bases is None or name in wmf_bases else m for name, m in zip(bases, maps)]
        result = (torch.cat(filtered, 1), *result[1:])
    return (*result, *costs)


@register("sgm-refine", kind="learned", needs_weights=True,
          description="A learned per-pixel choice between siamese-census-sgm's and sgm's filled maps (weights/refine.pt), then an image-guided weighted median")
def sgm_refine_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint: str | None = None,
                       backend: str = "torch", wmf_radius: int = WMF_RADIUS, wmf_sigma_color: float = WMF_SIGMA_COLOR,
                       wmf_stride: int = WMF_STRIDE, base_wmf_radius: int = 0,
                       base_wmf_bases: tuple[str, ...] | None = None, prefilter: str | None = None,
                       **options) -> StereoOutput:
    """The maps of the weights file's base matchers (its ``bases``; options go to ``sgm``), each with its invalid
    pixels filled, then :class:`~stereonet.models.refine.RefineNet` reads the images and the maps with their
    validity and confidence and returns, per pixel, a residual on the map or (``select`` files) one of the
    candidate values. The shipped ``refine.pt`` chooses between ``siamese-census-sgm`` and ``sgm`` at each pixel
    (model card, seventeenth session); older files refine ``sgm`` alone. Then, unless ``wmf_radius`` is 0, the
    image-guided weighted median (:func:`~stereonet.select.filters.weighted_median_filter`, radius ``wmf_radius``,
    ``wmf_sigma_color``, votes every ``wmf_stride`` px of the window, capped at the radius) near the map's
    discontinuities, against foreground fattening (model card, thirty-second and thirty-third sessions);
    ``extras["unfiltered"]`` keeps the choice's own map. ``base_wmf_radius`` (0 = off): the base maps (those named
    in ``base_wmf_bases``, None = all) go through the same filter (that radius, ``wmf_sigma_color``) before the
    network reads them (every pixel of the window votes, as those networks were trained); a weights file whose
    network was trained on filtered maps (``filtered_bases``) gets them so by default. ``prefilter``: the census
    cost of both SGM-family bases reads pre-filtered images (``sgm``'s option; :func:`refine_bases`). Every pixel
    is valid;
    the confidence is the first map's (the choice does not re-rank it). ``backend``: "torch" only."""
    if backend != "torch":
        raise StereoInputError(f"backend: sgm-refine runs on 'torch' only, got {backend!r}")
    check_wmf_options(wmf_radius, wmf_sigma_color, wmf_stride)
    check_wmf_options(base_wmf_radius, wmf_sigma_color, radius_name="base_wmf_radius")
    net = load_network("refine", checkpoint)
    check_trained_on(*_file_key(checkpoint if checkpoint is not None else default_weights_path("refine")))
    cross = getattr(net, "evidence", "pixel") == "cross"
    wmf, wmf_bases = None, None
    if base_wmf_radius:  # the caller's choice
        wmf, wmf_bases = (base_wmf_radius, wmf_sigma_color), base_wmf_bases
    elif getattr(net, "filtered_bases", ()):  # a network trained on filtered maps reads them so
        wmf, wmf_bases = (WMF_RADIUS, WMF_SIGMA_COLOR), net.filtered_bases
    base, valid, confidence, *costs = refine_bases(net.bases, left, right, max_disp, cross=cross,
                                                   wmf=wmf, wmf_bases=wmf_bases, prefilter=prefilter, **options)
    dtype = next(net.parameters()).dtype  # the network's own precision; the map comes back in the input's
    with torch.no_grad():
        disp = net.to(left.device)(left.to(dtype), right.to(dtype), base.to(dtype), valid, confidence.to(dtype),
                                   max_disp, costs[0].to(dtype) if cross else None).to(left.dtype)
    extras = {"base": base[:, :1]}
    if wmf_radius:
        extras["unfiltered"] = disp
        disp = weighted_median_filter(disp, left, radius=wmf_radius, sigma_color=wmf_sigma_color,
                                      stride=min(wmf_stride, wmf_radius))
    return StereoOutput(disp, torch.ones_like(valid[:, :1]), confidence=confidence[:, :1], extras=extras)


@register("sgm-penalties", kind="learned", needs_weights=True,
          description="sgm with learned large-jump penalties per pixel and path (SGM-Net style; no weights shipped: checkpoint=)")
def sgm_penalties_matcher(left: torch.Tensor, right: torch.Tensor, max_disp: int, checkpoint: str | None = None,
                          backend: str = "torch", **options) -> StereoOutput:
    """``sgm`` (its census cost, ``P1``, selection, filters and confidence; options as for ``sgm``) with the large-jump
    penalty of every pixel and path direction set by :class:`~stereonet.models.penalty.PenaltyNet` from the left
    image: ``sgm``'s edge-adapted rule (its ``P2`` and ``p2_alpha``) times the network's factor, within
    ``[P1, p2_max]``; a file with ``inputs="image+disparity"`` also reads a first ``sgm`` pass (filled, with its
    validity), so ``sgm`` runs twice. ``backend``: "torch" only (the network is a few convolutions; the
    aggregation is ``sgm``'s)."""
    from stereonet.aggregate.sgm import CENSUS_PENALTY_STEP, check_sgm_options, p2_maps
    from stereonet.matchers.local import SGM_DEFAULTS, sgm

    if backend != "torch":
        raise StereoInputError(f"backend: sgm-penalties runs on 'torch' only, got {backend!r}")
    for key in ("p2_maps", "cost", "block_size"):
        if key in options:
            raise StereoInputError(f"{key}: sgm-penalties sets its own (the learned maps on sgm's pixelwise census)")
    net = load_network("penalty", checkpoint)
    opts = {**SGM_DEFAULTS, **options}
    P1, P2, p2_alpha, paths = opts["P1"], opts["P2"], opts["p2_alpha"], opts["paths"]
    directions = check_sgm_options(P1, P2, paths, p2_alpha, CENSUS_PENALTY_STEP)
    if len(directions) != net.paths:
        raise StereoInputError(f"paths: the penalty network was trained for {net.paths} paths, got {paths}")
    b, _, h, w = left.shape
    dtype = next(net.parameters()).dtype
    first = valid = None
    if net.inputs == "image+disparity":  # the network reads a first pass of sgm with the same options
        first, valid, _ = sgm_base(left, right, max_disp, **options)
        first = first.to(dtype)
    with torch.no_grad():
        rule = p2_maps(P1, P2, directions, left, (b, h, w), p2_alpha, torch.float32, left.device, CENSUS_PENALTY_STEP)
        maps = net.to(left.device).penalties(left.to(dtype), rule, P1, first, valid)
    return sgm(left, right, max_disp, p2_maps=maps, **options)
