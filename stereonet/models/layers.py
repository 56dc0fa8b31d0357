"""Building blocks shared by the learned matchers: conv blocks, 1-D correlation, padding to a stride.

Everything here is stateless between calls (no tensors stored on ``self`` during ``forward``).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from stereonet.checks import StereoInputError


def conv_block(in_channels: int, out_channels: int, kernel_size: int = 3, stride: int = 1) -> nn.Sequential:
    """Conv2d ("same" padding for stride 1) followed by LeakyReLU(0.1), as in DispNet."""
    return nn.Sequential(
        nn.Conv2d(in_channels, out_channels, kernel_size, stride=stride, padding=kernel_size // 2),
        nn.LeakyReLU(0.1, inplace=True),
    )


class PlaneConv3d(nn.Conv3d):
    """A 3x3x3 ``nn.Conv3d`` (stride 1, "same" padding; the same parameters and state dict) computed as three 2-D
    convolutions over the volume's depth planes, summed with a shift of one plane: torch's CPU build runs 3-D
    convolutions through a slow im2col path (``slow_conv3d``, ~1.5 GB of scratch on a KITTI-sized volume) and
    2-D ones through oneDNN. Same maths; the float sums run in another order. ``dilation`` spaces the kernel's
    taps over (y, x) only (``nn.Conv3d``'s ``dilation=(1, s, s)`` with padding ``(1, s, s)``): a wider spatial
    reach for the same parameters and work; neighbouring depth planes stay one apart."""

    def __init__(self, in_channels: int, out_channels: int, dilation: int = 1) -> None:
        if isinstance(dilation, bool) or not isinstance(dilation, int) or dilation < 1:
            raise StereoInputError(f"dilation: expected an integer >= 1, got {dilation!r}")
        super().__init__(in_channels, out_channels, 3, padding=(1, dilation, dilation), dilation=(1, dilation, dilation))
        self.spatial_dilation = dilation

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, d, h, w = x.shape
        planes = x.transpose(1, 2).reshape(b * d, c, h, w)
        s = self.spatial_dilation
        per_k = [F.conv2d(planes, self.weight[:, :, k], None, padding=s, dilation=s).view(b, d, -1, h, w)
                 for k in range(3)]
        below = F.pad(per_k[0][:, :-1], (0, 0, 0, 0, 0, 0, 1, 0))  # plane z - 1 through the kernel's first slice
        above = F.pad(per_k[2][:, 1:], (0, 0, 0, 0, 0, 0, 0, 1))  # plane z + 1 through its last slice
        out = (below + per_k[1]) + above
        if self.bias is not None:
            out = out + self.bias.view(1, 1, -1, 1, 1)
        return out.transpose(1, 2)


def conv3d_block(in_channels: int, out_channels: int, dilation: int = 1) -> nn.Sequential:
    """3x3x3 convolution (:class:`PlaneConv3d`, "same" padding, spatial ``dilation``) + LeakyReLU(0.1), for cost
    volumes :math:`(B, C, D, H, W)`."""
    return nn.Sequential(PlaneConv3d(in_channels, out_channels, dilation), nn.LeakyReLU(0.1, inplace=True))


def upconv_block(in_channels: int, out_channels: int) -> nn.Sequential:
    """x2 transposed-conv upsampling followed by LeakyReLU(0.1): (B, Cin, H, W) -> (B, Cout, 2H, 2W)."""
    return nn.Sequential(
        nn.ConvTranspose2d(in_channels, out_channels, 4, stride=2, padding=1),
        nn.LeakyReLU(0.1, inplace=True),
    )


def image_mean_std(image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-image, per-channel mean and (unbiased) std, each :math:`(B, C, 1, 1)`, of ``image`` :math:`(B, C, H, W)`.

    Accumulated in float64 (float32 on MPS, which has no float64) and returned in the image's dtype: a
    float32 sum over a photo's 10^5-10^6 pixels is only as exact as the runtime's summation order
    (onnxruntime's was ~1e-4 off on a 464x384 pair, which DispNet's correlation turned into 0.05 px of
    disparity); in float64 torch and onnxruntime agree to float32 precision.
    """
    stats = image.to(torch.float32 if image.device.type == "mps" else torch.float64)
    mean, std = stats.mean(dim=(2, 3), keepdim=True), stats.std(dim=(2, 3), keepdim=True)
    return mean.to(image.dtype), std.to(image.dtype)


def standardize_image(image: torch.Tensor, grey: bool = False) -> torch.Tensor:
    """The one image standardisation of the networks: per-image, per-channel zero mean / unit std (+ 0.01),
    so they see the same statistics on any photo.

    image: :math:`(B, C, H, W)` in [0, 1]. ``grey=False`` (DispNet, SMD): grey (C = 1) is repeated to 3
    channels, returns :math:`(B, 3, H, W)`; ``grey=True`` (the Siamese tower, as MC-CNN normalises): the
    channel mean is standardised, returns :math:`(B, 1, H, W)`.
    """
    if grey:
        image = image.mean(dim=1, keepdim=True) if image.shape[1] != 1 else image
    elif image.shape[1] == 1:
        image = image.expand(-1, 3, -1, -1)
    mean, std = image_mean_std(image)
    return (image - mean) / (std + 1e-2)  # 1e-2: keeps flat images finite (std is ~0.2 on natural images)


def unit_channels(x: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Scale each pixel's feature vector to unit length: :math:`(B, C, H, W)` -> same (``F.normalize`` along
    channels, written as a sum of squares because torch's strided channel norm is several times slower on CPU)."""
    return x * torch.rsqrt((x * x).sum(dim=1, keepdim=True) + eps * eps)


def warp_right(feat_right: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
    """Sample the right view at ``x - disparity`` (bilinear, zeros outside): the right features seen from the
    left view. feat_right :math:`(B, C, H, W)`, disparity :math:`(B, 1, H, W)` in pixels of this scale."""
    b, _, h, w = feat_right.shape
    xs = torch.arange(w, device=feat_right.device, dtype=feat_right.dtype).view(1, 1, w) - disparity[:, 0]
    ys = torch.arange(h, device=feat_right.device, dtype=feat_right.dtype).view(1, h, 1).expand(b, h, w)
    grid = torch.stack([2.0 * xs / max(w - 1, 1) - 1.0, 2.0 * ys / max(h - 1, 1) - 1.0], dim=-1)  # BxHxWx2
    return F.grid_sample(feat_right, grid, mode="bilinear", padding_mode="zeros", align_corners=True)


def warped_correlation(feat_left: torch.Tensor, feat_right: torch.Tensor, disparities: torch.Tensor) -> torch.Tensor:
    """Correlation of the left features with the right ones warped by each of K per-pixel disparities.

    ``similarity[b, k, y, x] = mean_c feat_left[b, c, y, x] * feat_right[b, c, y, x - disparities[b, k, y, x]]``
    (bilinear in x, zeros outside). Args: features :math:`(B, C, H, W)`, disparities :math:`(B, K, H, W)` in
    pixels of this scale. Returns :math:`(B, K, H, W)`, differentiable in the features and the disparities.
    """
    if feat_left.shape != feat_right.shape:
        raise StereoInputError(f"feat_right: expected shape {tuple(feat_left.shape)}, got {tuple(feat_right.shape)}")
    return torch.stack([(feat_left * warp_right(feat_right, disparities[:, k:k + 1])).mean(dim=1)
                        for k in range(disparities.shape[1])], dim=1)  # BxKxHxW


def local_correlation(feat_left: torch.Tensor, feat_right: torch.Tensor, disparity: torch.Tensor,
                      radius: int) -> torch.Tensor:
    """Correlation of the left features with the right ones warped by ``disparity + s``, s = -radius..radius.

    ``similarity[b, k, y, x] = mean_c feat_left[b, c, y, x] * feat_right[b, c, y, x - disparity - (k - radius)]``
    (bilinear in x). Args: features :math:`(B, C, H, W)`, disparity :math:`(B, 1, H, W)` in pixels of this
    scale. Returns :math:`(B, 2 radius + 1, H, W)`, differentiable in the features and the disparity.
    """
    shifts = torch.arange(-radius, radius + 1, device=disparity.device, dtype=disparity.dtype).view(1, -1, 1, 1)
    return warped_correlation(feat_left, feat_right, disparity + shifts)


class InputPadder:
    """Pad images on the right/bottom (replicate) to a multiple of ``stride``; ``unpad`` removes exactly that.

    Nothing is ever cropped from the input: the output has the input's size.
    """

    def __init__(self, height: int, width: int, stride: int) -> None:
        self.height, self.width = int(height), int(width)
        self.pad_h = (-self.height) % stride
        self.pad_w = (-self.width) % stride

    def pad(self, *images: torch.Tensor) -> list[torch.Tensor]:
        """(B, C, H, W) -> (B, C, H + pad_h, W + pad_w) each."""
        if self.pad_h == 0 and self.pad_w == 0:
            return list(images)
        return [F.pad(x, (0, self.pad_w, 0, self.pad_h), mode="replicate") for x in images]

    def unpad(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C, H + pad_h, W + pad_w) -> (B, C, H, W)."""
        return x[..., : self.height, : self.width]


def resize_disparity(disp: torch.Tensor, height: int, width: int, mode: str = "bilinear") -> torch.Tensor:
    """Resize a disparity map :math:`(B, 1, h, w)` to ``(height, width)`` and rescale its values by ``width / w``."""
    scale = width / disp.shape[-1]
    kwargs = {"align_corners": False} if mode in ("bilinear", "bicubic") else {}
    return F.interpolate(disp, size=(height, width), mode=mode, **kwargs) * scale


def round_up(x: int, multiple: int) -> int:
    return int(math.ceil(x / multiple) * multiple)
