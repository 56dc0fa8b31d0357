"""Pinhole cameras with optional OpenCV radial/tangential distortion, and the ray sets they generate.

World frame = left camera frame. A camera maps world points to its frame by ``X_cam = R X + t`` (so the
right camera of a rig carries exactly the calibration's ``R, t``: ``X_r = R X_l + t``). Pixel ``(x, y)``
covers ``[x - 0.5, x + 0.5] x [y - 0.5, y + 0.5]``; pixel centres are integer coordinates.

Ray directions are ``R^T (x_n, y_n, 1)`` with undistorted normalized coordinates ``(x_n, y_n)``, so the ray
parameter ``t`` of a hit equals the hit's depth ``z`` in that camera's frame.

This is the one camera model of the project: :mod:`stereonet.geometry.camera` holds the same projection as
differentiable functions of ``K, R, t, dist`` (tested equal in ``tests/geometry/test_camera_models.py``),
and :mod:`stereonet.active` uses these cameras (and projectors) directly; :meth:`Camera.pinhole` with
:func:`look_at` builds one from a focal length, an image size and a viewpoint.

Ray sets expose the few scalar products the primitives need (``w . d``, ``w . o``, ``d . d``, ``d . o``,
``o . o``) instead of the directions themselves, so that on an undistorted grid every linear functional
``w . d = a x + b y + c`` is one broadcast add of a row and a column vector.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch


def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera pose ``(R, t)`` of a camera at ``eye`` looking at ``target``, ``up`` at the top of the image.

    The default ``up = -y`` suits a y-down world like the camera frame (x right, y down, z forward), in which
    the identity pose looks down +z. The rows of ``R`` are the camera axes in world coordinates and
    ``t = -R eye``, so that ``X_cam = R X + t``.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64).reshape(3) for v in (eye, target, up))
    for name, v in (("eye", eye), ("target", target), ("up", up)):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{name}: expected finite values, got {v.tolist()}")
    z = target - eye
    if np.linalg.norm(z) < 1e-12:
        raise ValueError("target: expected a point different from eye")
    z = z / np.linalg.norm(z)
    x = np.cross(-up, z)  # camera x (right) = down x forward (x = y x z in a right-handed frame)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("up: expected a direction not parallel to the viewing direction")
    x = x / np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ eye


@dataclass
class Camera:
    """A pinhole camera.

    Attributes:
        K: intrinsics :math:`(3, 3)` (no skew); R: world-to-camera rotation :math:`(3, 3)`; t: :math:`(3,)`.
        size: ``(width, height)`` in pixels.
        dist: OpenCV distortion ``(k1, k2, p1, p2, k3)`` or None.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]
    dist: np.ndarray | None = None
    _bbox_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)
        if self.dist is not None:
            d = np.zeros(5)
            given = np.asarray(self.dist, dtype=np.float64).reshape(-1)[:5]
            d[: given.size] = given
            self.dist = None if not np.any(d) else d
        w, h = (int(v) for v in self.size)
        if w <= 0 or h <= 0:
            raise ValueError(f"size: expected positive (width, height), got {self.size}")
        self.size = (w, h)

    @classmethod
    def pinhole(cls, focal: float, width: int, height: int, eye=(0.0, 0.0, 0.0), target=None,
                up=(0.0, -1.0, 0.0), cx: float | None = None, cy: float | None = None, dist=None) -> Camera:
        """A camera of square pixels with focal length ``focal`` (pixels) and image ``width x height``.

        The principal point is the image centre ``((W - 1) / 2, (H - 1) / 2)`` unless ``cx``, ``cy`` are given;
        the centre of projection is ``eye``. With ``target`` the camera looks at it (:func:`look_at`, ``up`` at
        the top of the image); without, it keeps the world axes (looks down +z).
        """
        cx = (width - 1) / 2.0 if cx is None else float(cx)
        cy = (height - 1) / 2.0 if cy is None else float(cy)
        K = np.array([[float(focal), 0.0, cx], [0.0, float(focal), cy], [0.0, 0.0, 1.0]])
        if target is None:
            eye = np.asarray(eye, dtype=np.float64).reshape(3)
            R, t = np.eye(3), -eye
        else:
            R, t = look_at(eye, target, up)
        return cls(K, R, t, (width, height), dist)

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates :math:`(3,)`."""
        return -self.R.T @ self.t

    def relative_to(self, other: Camera) -> tuple[np.ndarray, np.ndarray]:
        """Pose of this camera in ``other``'s frame: ``X_self = R X_other + t``, ``R`` :math:`(3, 3)`, ``t`` :math:`(3,)`."""
        R = self.R @ other.R.T
        return R, self.t - R @ other.t

    # -- distortion -------------------------------------------------------------------------------
    def distort(self, xn, yn):
        """OpenCV distortion of normalized coordinates (numpy or torch arrays of equal shape)."""
        if self.dist is None:
            return xn, yn
        k1, k2, p1, p2, k3 = (float(v) for v in self.dist)
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        return xd, yd

    def undistort(self, xd, yd, iterations: int = 30):
        """Inverse of :meth:`distort` by fixed-point iteration (exact to ~1e-10 for moderate distortion)."""
        if self.dist is None:
            return xd, yd
        k1, k2, p1, p2, k3 = (float(v) for v in self.dist)
        xn, yn = xd, yd
        for _ in range(iterations):
            r2 = xn * xn + yn * yn
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
            dy = p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
            xn = (xd - dx) / radial
            yn = (yd - dy) / radial
        return xn, yn

    # -- projection -------------------------------------------------------------------------------
    def to_camera(self, points: torch.Tensor) -> torch.Tensor:
        """World points :math:`(*, 3)` to camera coordinates :math:`(*, 3)`."""
        if not np.any(self.R - np.eye(3)):
            return points + torch.as_tensor(self.t, dtype=points.dtype)
        R = torch.as_tensor(self.R, dtype=points.dtype)
        t = torch.as_tensor(self.t, dtype=points.dtype)
        return points @ R.T + t

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Project world points :math:`(*, 3)` to pixels :math:`(*, 2)` (with distortion) and depths :math:`(*)`."""
        pc = self.to_camera(points)
        z = pc[..., 2]
        zs = torch.where(z.abs() > 1e-12, z, torch.full_like(z, 1e-12))
        xd, yd = self.distort(pc[..., 0] / zs, pc[..., 1] / zs)
        K = self.K
        x = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
        y = K[1, 1] * yd + K[1, 2]
        return torch.stack([x, y], dim=-1), z

    def pixel_to_normalized(self, x, y):
        """Pixel coordinates to undistorted normalized coordinates."""
        K = self.K
        yd = (y - K[1, 2]) / K[1, 1]
        xd = (x - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        return self.undistort(xd, yd)

    def ray_dirs(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """World directions :math:`(N, 3)` of the rays through pixel coordinates ``x, y`` :math:`(N,)`, scaled to
        camera-frame z = 1 (a ray parameter is the depth), in the dtype of ``x``; the rays start at :attr:`center`."""
        xn, yn = self.pixel_to_normalized(x.double(), y.double())
        d_cam = torch.stack([xn, yn, torch.ones_like(xn)], dim=-1)
        return (d_cam @ torch.as_tensor(self.R)).to(x.dtype)  # rows R^T d_cam

    def sample_coords(self, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates of the sample grid: xs :math:`(W s,)`, ys :math:`(H s,)`.

        With ``supersample = s`` pixel ``i`` holds samples at ``i - 0.5 + (k + 0.5) / s``, k < s; s = 1 gives
        the pixel centres.
        """
        s = int(supersample)
        xs = np.arange(self.width * s) / s - 0.5 + 0.5 / s
        ys = np.arange(self.height * s) / s - 0.5 + 0.5 / s
        return xs, ys

    def grid_rays(self, supersample: int = 1, dtype: torch.dtype = torch.float32) -> GridRays:
        xs, ys = self.sample_coords(supersample)
        return GridRays(self, xs, ys, dtype)

    def pixel_bbox(self, centre: np.ndarray, radius: float, margin: float = 1.5) -> tuple[float, float, float, float] | None:
        """Conservative pixel bounding box ``(x0, x1, y0, y1)`` of a world sphere, or None if surely unseen.

        Returns the whole (unbounded) plane ``(-inf, inf, -inf, inf)`` when the sphere reaches behind the
        camera. Results are cached per (centre, radius, margin).
        """
        key = (*np.asarray(centre, dtype=np.float64).tolist(), float(radius), float(margin))
        if key not in self._bbox_cache:
            self._bbox_cache[key] = self._pixel_bbox(np.asarray(centre, dtype=np.float64), radius, margin)
        return self._bbox_cache[key]

    def pixel_bboxes(self, centres: np.ndarray, radii: np.ndarray, margin: float = 1.5) -> np.ndarray:
        """:meth:`pixel_bbox` of K spheres at once: ``(K, 4)`` rows ``(x0, x1, y0, y1)``, ``(-inf, inf, -inf,
        inf)`` for spheres reaching behind the camera and NaN rows for spheres surely unseen."""
        centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
        radii = np.asarray(radii, dtype=np.float64).reshape(-1)
        k = centres.shape[0]
        out = np.empty((k, 4))
        if k == 0:
            return out
        pc = (centres[:, None, :] + radii[:, None, None] * _BOX_CORNERS[None]) @ self.R.T + self.t  # Kx8x3
        z = pc[..., 2]
        behind = np.any(z <= 1e-9, axis=1)
        unseen = np.all(z <= 1e-9, axis=1)
        zs = np.where(z > 1e-9, z, 1.0)
        xn, yn = pc[..., 0] / zs, pc[..., 1] / zs
        x0, x1, y0, y1 = xn.min(1), xn.max(1), yn.min(1), yn.max(1)
        m = margin
        if self.dist is not None:  # distort the rectangles' boundaries; interiors map inside them
            s = np.linspace(0.0, 1.0, 33)[None, :]
            dx, dy = (x1 - x0)[:, None], (y1 - y0)[:, None]
            bx = np.concatenate([x0[:, None] + dx * s, np.repeat(x1[:, None], 33, 1), x1[:, None] - dx * s,
                                 np.repeat(x0[:, None], 33, 1)], axis=1)
            by = np.concatenate([np.repeat(y0[:, None], 33, 1), y0[:, None] + dy * s, np.repeat(y1[:, None], 33, 1),
                                 y1[:, None] - dy * s], axis=1)
            bx, by = self.distort(bx, by)
            x0, x1, y0, y1 = bx.min(1), bx.max(1), by.min(1), by.max(1)
            m = margin + 2.0
        K = self.K
        skew = abs(K[0, 1]) * np.maximum(np.abs(y0), np.abs(y1))
        out[:, 0] = np.minimum(K[0, 0] * x0, K[0, 0] * x1) + K[0, 2] - skew - m
        out[:, 1] = np.maximum(K[0, 0] * x0, K[0, 0] * x1) + K[0, 2] + skew + m
        out[:, 2] = np.minimum(K[1, 1] * y0, K[1, 1] * y1) + K[1, 2] - m
        out[:, 3] = np.maximum(K[1, 1] * y0, K[1, 1] * y1) + K[1, 2] + m
        out[behind] = (-np.inf, np.inf, -np.inf, np.inf)
        out[unseen] = np.nan
        return out

    def _pixel_bbox(self, centre: np.ndarray, radius: float, margin: float):
        pc = (centre[None, :] + radius * _BOX_CORNERS) @ self.R.T + self.t  # 8x3, box around the sphere
        if np.any(pc[:, 2] <= 1e-9):
            if np.all(pc[:, 2] <= 1e-9):
                return None
            return (-np.inf, np.inf, -np.inf, np.inf)
        xn = pc[:, 0] / pc[:, 2]
        yn = pc[:, 1] / pc[:, 2]
        x0, x1, y0, y1 = xn.min(), xn.max(), yn.min(), yn.max()
        if self.dist is not None:  # distort the rectangle's boundary; interior maps inside it
            s = np.linspace(0.0, 1.0, 33)
            bx = np.concatenate([x0 + (x1 - x0) * s, np.full_like(s, x1), x1 - (x1 - x0) * s, np.full_like(s, x0)])
            by = np.concatenate([np.full_like(s, y0), y0 + (y1 - y0) * s, np.full_like(s, y1), y1 - (y1 - y0) * s])
            bx, by = self.distort(bx, by)
            x0, x1, y0, y1 = bx.min(), bx.max(), by.min(), by.max()
            margin += 2.0
        K = self.K
        skew = abs(K[0, 1]) * max(abs(y0), abs(y1))
        px = np.array([K[0, 0] * x0 + K[0, 2] - skew, K[0, 0] * x1 + K[0, 2] + skew])
        py = K[1, 1] * np.array([y0, y1]) + K[1, 2]
        return (float(px.min() - margin), float(px.max() + margin), float(py.min() - margin), float(py.max() + margin))


_BOX_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)


def _dot3(w) -> np.ndarray:
    return np.asarray(w, dtype=np.float64).reshape(3)


class GridRays:
    """All rays of one camera through a regular grid of pixel coordinates ``xs`` :math:`(W',)`, ``ys`` :math:`(H',)`.

    Undistorted cameras keep directions implicit (``d = M (x, y, 1)``, ``M = R^T K^-1``); distorted cameras
    store them :math:`(H', W', 3)`. Use :meth:`block` to get the rays of a sub-rectangle.
    """

    def __init__(self, camera: Camera, xs: np.ndarray, ys: np.ndarray, dtype: torch.dtype = torch.float32):
        self.camera = camera
        self.dtype = dtype
        self.xs_np = np.asarray(xs, dtype=np.float64)
        self.ys_np = np.asarray(ys, dtype=np.float64)
        self.xs = torch.as_tensor(self.xs_np, dtype=dtype)
        self.ys = torch.as_tensor(self.ys_np, dtype=dtype)
        self.origin = camera.center
        self.shape = (len(ys), len(xs))
        if camera.dist is None:
            self.M = camera.R.T @ np.linalg.inv(camera.K)
            self.dirs_field = None
        else:
            X, Y = np.meshgrid(self.xs_np, self.ys_np)
            xn, yn = camera.pixel_to_normalized(X, Y)
            d_cam = np.stack([xn, yn, np.ones_like(xn)], axis=-1)  # H'xW'x3
            self.M = None
            self.dirs_field = torch.as_tensor(d_cam @ camera.R, dtype=dtype)  # rows are R^T d_cam
        self._dd = None

    def index_range(self, bbox: tuple[float, float, float, float] | None) -> tuple[int, int, int, int] | None:
        """Sample index ranges ``(r0, r1, c0, c1)`` covered by a pixel bbox, or None if empty."""
        if bbox is None:
            return None
        x0, x1, y0, y1 = bbox
        c0 = int(np.searchsorted(self.xs_np, x0, side="left"))
        c1 = int(np.searchsorted(self.xs_np, x1, side="right"))
        r0 = int(np.searchsorted(self.ys_np, y0, side="left"))
        r1 = int(np.searchsorted(self.ys_np, y1, side="right"))
        if c1 <= c0 or r1 <= r0:
            return None
        return r0, r1, c0, c1

    def dirs(self) -> torch.Tensor:
        """All directions :math:`(H', W', 3)` (materialized on demand)."""
        if self.dirs_field is not None:
            return self.dirs_field
        M = torch.as_tensor(self.M, dtype=self.dtype)
        return (self.xs[None, :, None] * M[:, 0] + self.ys[:, None, None] * M[:, 1] + M[:, 2])

    def dirs_at(self, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
        """Directions :math:`(N, 3)` of the samples at integer ``rows``, ``cols`` :math:`(N,)`."""
        if self.dirs_field is not None:
            return self.dirs_field[rows, cols]
        M = torch.as_tensor(self.M, dtype=self.dtype)
        return self.xs[cols][:, None] * M[:, 0] + self.ys[rows][:, None] * M[:, 1] + M[:, 2]

    def dd(self) -> torch.Tensor:
        if self._dd is None:
            d = self.dirs()
            self._dd = (d * d).sum(-1)
        return self._dd

    def block(self, r0: int = 0, r1: int | None = None, c0: int = 0, c1: int | None = None) -> GridBlock:
        r1 = self.shape[0] if r1 is None else r1
        c1 = self.shape[1] if c1 is None else c1
        return GridBlock(self, r0, r1, c0, c1)


class GridBlock:
    """Rays of a rectangular block ``[r0:r1, c0:c1]`` of a :class:`GridRays` (results have shape (h, w))."""

    def __init__(self, grid: GridRays, r0: int, r1: int, c0: int, c1: int):
        self.grid, self.r0, self.r1, self.c0, self.c1 = grid, r0, r1, c0, c1
        self.o = grid.origin
        self.oo = float(self.o @ self.o)

    def dot_d(self, w) -> torch.Tensor:
        """``w . d`` for every ray of the block, :math:`(h, w)`."""
        g = self.grid
        w = _dot3(w)
        if g.M is not None:
            a, b, c = (float(v) for v in g.M.T @ w)
            return (g.xs[self.c0:self.c1] * a)[None, :] + (g.ys[self.r0:self.r1] * b + c)[:, None]
        return g.dirs_field[self.r0:self.r1, self.c0:self.c1] @ torch.as_tensor(w, dtype=g.dtype)

    def dot_o(self, w) -> float:
        return float(self.o @ _dot3(w))

    def dd(self) -> torch.Tensor:
        return self.grid.dd()[self.r0:self.r1, self.c0:self.c1]

    def do(self) -> torch.Tensor:
        return self.dot_d(self.o)


class PointRays:
    """Explicit rays: ``origins`` :math:`(3,)` (shared) or :math:`(N, 3)`, ``dirs`` :math:`(N, 3)`."""

    def __init__(self, origins, dirs: torch.Tensor):
        self.dirs = dirs
        o = torch.as_tensor(origins, dtype=dirs.dtype)
        self.shared = o.dim() == 1
        if self.shared:
            self.o = o.double().numpy()
            self.oo = float(self.o @ self.o)
        else:
            self.o_t = o
            self.oo = (o * o).sum(-1)

    def subset(self, index: torch.Tensor) -> PointRays:
        return PointRays(self.o if self.shared else self.o_t[index], self.dirs[index])

    def dot_d(self, w) -> torch.Tensor:
        return self.dirs @ torch.as_tensor(_dot3(w), dtype=self.dirs.dtype)

    def dot_o(self, w):
        if self.shared:
            return float(self.o @ _dot3(w))
        return self.o_t @ torch.as_tensor(_dot3(w), dtype=self.dirs.dtype)

    def dd(self) -> torch.Tensor:
        return (self.dirs * self.dirs).sum(-1)

    def do(self) -> torch.Tensor:
        if self.shared:
            return self.dot_d(self.o)
        return (self.dirs * self.o_t).sum(-1)
