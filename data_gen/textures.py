"""Procedural textures, evaluated in each surface's own (u, v) coordinates.

Two families:

* **Bank textures** — periodic grey images of ``BANK_SIZE x BANK_SIZE`` texels with natural-image statistics
  (dead-leaves with discs or squares, 1/f^alpha fractal noise, Voronoi cells), generated lazily from a fixed
  seed per bank index (so every worker sees the same bank) and sampled bilinearly with wrap-around.
* **Analytic textures** — stripes, grids, checkers, flat colour, evaluated directly per ray hit.

A :class:`Material` maps (u, v) in scene units (mm) to an RGB albedo ``(N, 3)`` in [0, 1]; its
``texel_mm`` sets how many scene units one texel covers, chosen by the scene sampler so that one texel
spans about one to three pixels at the object's depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numba
import numpy as np
import torch

BANK_SIZE = 256  # texels per side of a bank texture (a power of two: wrap-around is a bit mask)
BANK_COUNT = 96  # distinct bank textures; each is generated on first use, then cached per process
_BANK_SEED = 20240611
BANK_KINDS = ("dead_leaves_discs", "fractal", "dead_leaves_squares", "voronoi")

TEXTURE_KINDS = ("bank", "bank_mix", "stripes", "grid", "checker", "weak", "flat")


def _fractal(rng: np.random.Generator, size: int) -> np.ndarray:
    """Periodic 1/f^alpha noise, alpha in [0.8, 1.8] (amplitude spectrum), stretched to [0, 1]."""
    alpha = rng.uniform(0.8, 1.8)
    fy = np.fft.fftfreq(size)[:, None]
    fx = np.fft.rfftfreq(size)[None, :]
    f = np.sqrt(fx * fx + fy * fy)
    f[0, 0] = 1.0
    amp = f ** (-alpha)
    amp[0, 0] = 0.0
    spec = amp * np.exp(2j * np.pi * rng.random(amp.shape))
    img = np.fft.irfft2(spec, s=(size, size))
    lo, hi = np.percentile(img, [1, 99])
    return np.clip((img - lo) / max(hi - lo, 1e-12), 0.0, 1.0)


@numba.njit(cache=True)
def _paint_leaves(img, centres, radii, values, squares):  # pragma: no cover - compiled
    """Paint leaves back to front on a periodic canvas (later leaves cover earlier ones)."""
    size = img.shape[0]
    for i in range(radii.shape[0]):
        cy, cx, r = centres[i, 0], centres[i, 1], radii[i]
        ri = int(np.ceil(r))
        y0, x0 = int(cy) - ri, int(cx) - ri
        for yy in range(y0, y0 + 2 * ri + 1):
            dy = yy - cy + 0.5
            for xx in range(x0, x0 + 2 * ri + 1):
                dx = xx - cx + 0.5
                inside = max(abs(dy), abs(dx)) <= r if squares else dy * dy + dx * dx <= r * r
                if inside:
                    img[yy % size, xx % size] = values[i]


def _dead_leaves(rng: np.random.Generator, size: int, squares: bool) -> np.ndarray:
    """Periodic dead-leaves image: occluding discs (or squares) with power-law radii r^-3, painted back to front."""
    rmin, rmax = rng.uniform(1.0, 2.5), rng.uniform(25.0, 60.0)
    n = 8000  # enough leaves to cover the tile several times over (a true dead-leaves image)
    u = rng.random(n)
    radii = (rmin ** -2 - u * (rmin ** -2 - rmax ** -2)) ** -0.5
    centres = rng.random((n, 2)) * size
    values = rng.random(n)
    img = np.full((size, size), rng.random())
    _paint_leaves(img, centres, radii, values, squares)
    return img


def _voronoi(rng: np.random.Generator, size: int) -> np.ndarray:
    """Periodic Voronoi cells with random grey levels plus a weak distance-to-seed shading."""
    from scipy.spatial import cKDTree

    n = int(rng.integers(60, 600))
    seeds = rng.random((n, 2)) * size
    values = rng.random(n)
    yy, xx = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="ij")
    dist, label = cKDTree(seeds, boxsize=size).query(np.stack([yy.ravel(), xx.ravel()], axis=-1))
    dist = dist.reshape(size, size)
    shade = dist / (dist.max() + 1e-12)
    return np.clip(0.85 * values[label.reshape(size, size)] + 0.15 * shade, 0.0, 1.0)


MIP_LEVELS = 6  # bank mip-map levels: 256, 128, ..., 8 texels per side
_MIP_OFFSETS = torch.tensor([sum((BANK_SIZE >> k) ** 2 for k in range(level)) for level in range(MIP_LEVELS + 1)])


@lru_cache(maxsize=BANK_COUNT)
def bank_texture(index: int) -> torch.Tensor:
    """Bank texture ``index`` (0 <= index < BANK_COUNT) as a flattened mip pyramid, float32, values in [0, 1].

    Level ``k`` (``BANK_SIZE >> k`` texels per side, 2x2 box-filtered from level k-1) starts at
    ``_MIP_OFFSETS[k]``. Deterministic (seeded by the index only), periodic in both axes, cached per process.
    """
    if not 0 <= index < BANK_COUNT:
        raise ValueError(f"index: expected 0 <= index < {BANK_COUNT}, got {index}")
    rng = np.random.default_rng([_BANK_SEED, index])
    kind = BANK_KINDS[index % len(BANK_KINDS)]
    if kind == "fractal":
        img = _fractal(rng, BANK_SIZE)
    elif kind == "voronoi":
        img = _voronoi(rng, BANK_SIZE)
    else:
        img = _dead_leaves(rng, BANK_SIZE, squares=kind == "dead_leaves_squares")
    levels = [img]
    for _ in range(1, MIP_LEVELS):
        a = levels[-1]
        levels.append(0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]))
    return torch.from_numpy(np.concatenate([a.ravel() for a in levels]).astype(np.float32))


def warm_bank() -> None:
    """Generate every bank texture now (e.g. before timing a benchmark)."""
    for i in range(BANK_COUNT):
        bank_texture(i)


def sample_bank(index: int, s: torch.Tensor, t: torch.Tensor, texels_per_sample: torch.Tensor | None = None
                ) -> torch.Tensor:
    """Bilinear, wrap-around lookup of bank texture ``index`` at texel coordinates ``(s, t)`` :math:`(N,)`.

    Texel ``(i, j)`` has its centre at ``(i + 0.5, j + 0.5)``. With ``texels_per_sample`` :math:`(N,)` (the
    footprint of one image sample on the texture) each lookup reads the mip level whose texels match the
    footprint, so textures do not alias. Returns :math:`(N,)` in the dtype of ``s``.
    """
    tex = bank_texture(index).to(s.dtype)
    if texels_per_sample is None:
        level = torch.zeros_like(s, dtype=torch.long)
    else:
        level = torch.floor(torch.log2(texels_per_sample.clamp(min=1.0)) + 0.5).long().clamp_(max=MIP_LEVELS - 1)
    scale = torch.ldexp(torch.ones_like(s), -level)  # 2^-level
    size = BANK_SIZE >> level
    mask = size - 1
    offset = _MIP_OFFSETS[level]
    x = s * scale - 0.5
    y = t * scale - 0.5
    x0f = torch.floor(x)
    y0f = torch.floor(y)
    fx = x - x0f
    fy = y - y0f
    x0 = x0f.long() & mask
    y0 = y0f.long() & mask
    x1 = (x0 + 1) & mask
    y1 = (y0 + 1) & mask
    r0 = y0 * size + offset
    r1 = y1 * size + offset
    top = tex[r0 + x0] * (1 - fx) + tex[r0 + x1] * fx
    bottom = tex[r1 + x0] * (1 - fx) + tex[r1 + x1] * fx
    return top * (1 - fy) + bottom * fy


def _smooth_square(phase: torch.Tensor, softness: float) -> torch.Tensor:
    """A square wave in [0, 1] from a sine phase, edges softened over ``softness`` of the period."""
    return torch.clamp(0.5 + torch.sin(phase) / (2 * max(softness, 1e-3) * math.pi), 0.0, 1.0)


@dataclass
class Material:
    """How a surface looks: albedo texture in (u, v), plus specular parameters.

    Attributes:
        kind: one of ``TEXTURE_KINDS``.
        colors: :math:`(3, 3)` RGB rows: base colour, colour of the first texture channel, colour of the
            second (``bank_mix``) channel; albedo = clip(c0 + g1 (c1 - c0) + (g2 - 0.5) c2).
        texel_mm: scene units per texel (bank) or per stripe period / 16 (analytic kinds).
        angle: rotation of the texture in the (u, v) plane, radians; offset: texel offset (2,).
        bank: bank texture indices (first, second); scale2: relative scale of the second bank texture.
        contrast: multiplies the texture signal around 0.5 (weak textures use ~0.03).
        period: stripe/grid/checker period in texels; duty: line thickness fraction for grids.
        specular: Blinn-Phong strength (0 = matte); shininess: exponent.
    """

    kind: str = "bank"
    colors: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]))
    texel_mm: float = 1.0
    angle: float = 0.0
    offset: tuple[float, float] = (0.0, 0.0)
    bank: tuple[int, int] = (0, 1)
    scale2: float = 2.7
    contrast: float = 1.0
    period: float = 16.0
    duty: float = 0.15
    specular: float = 0.0
    shininess: float = 30.0

    def __post_init__(self) -> None:
        if self.kind not in TEXTURE_KINDS:
            raise ValueError(f"kind: expected one of {TEXTURE_KINDS}, got {self.kind!r}")
        if not self.texel_mm > 0:
            raise ValueError(f"texel_mm: expected a positive size, got {self.texel_mm}")

    def _texel_coords(self, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        c, s = math.cos(self.angle), math.sin(self.angle)
        inv = 1.0 / self.texel_mm
        u = uv[:, 0]
        v = uv[:, 1]
        return (c * inv) * u - (s * inv) * v + self.offset[0], (s * inv) * u + (c * inv) * v + self.offset[1]

    def albedo(self, uv: torch.Tensor, footprint: torch.Tensor | None = None) -> torch.Tensor:
        """RGB albedo :math:`(N, 3)` in [0, 1] at surface coordinates ``uv`` :math:`(N, 2)` (scene units).

        ``footprint`` :math:`(N,)`: size of one image sample on the surface (scene units); when given, the
        texture is band-limited to it (mip levels for bank textures, contrast fading for periodic patterns).
        """
        s, t = self._texel_coords(uv)
        per_sample = None if footprint is None else footprint / self.texel_mm  # texels per image sample
        g2 = None
        if self.kind == "flat":
            g1 = torch.full_like(s, 0.5)
        elif self.kind in ("bank", "weak"):
            g1 = sample_bank(self.bank[0], s, t, per_sample)
        elif self.kind == "bank_mix":
            g1 = sample_bank(self.bank[0], s, t, per_sample)
            g2 = sample_bank(self.bank[1], s / self.scale2 + 17.0, t / self.scale2 + 5.0,
                             None if per_sample is None else per_sample / self.scale2)
        else:
            if self.kind == "stripes":
                g1 = _smooth_square(s * (2 * math.pi / self.period), 0.15)
                mean = 0.5
            elif self.kind == "grid":
                fs = torch.remainder(s / self.period, 1.0)
                ft = torch.remainder(t / self.period, 1.0)
                g1 = ((fs < self.duty) | (ft < self.duty)).to(s.dtype)
                mean = 1 - (1 - self.duty) ** 2
            else:  # checker
                w = 2 * math.pi / self.period
                g1 = _smooth_square(s * w, 0.1) * 2 - 1
                g1 = 0.5 + 0.5 * g1 * (_smooth_square(t * w, 0.1) * 2 - 1)
                mean = 0.5
            if per_sample is not None:  # fade patterns finer than ~3 samples per period to their mean
                keep = ((self.period / per_sample - 2.0) / 2.0).clamp(0.0, 1.0)
                g1 = mean + keep * (g1 - mean)
        if self.contrast != 1.0:
            g1 = 0.5 + self.contrast * (g1 - 0.5)
        cols = torch.as_tensor(np.asarray(self.colors), dtype=uv.dtype)
        rgb = cols[0] + g1[:, None] * (cols[1] - cols[0])
        if g2 is not None:
            rgb = rgb + (g2[:, None] - 0.5) * cols[2]
        return rgb.clamp_(0.0, 1.0)
