"""Where the scene is: sparse 3-D points and, per image, the range of depths and the ground height.

Pair selection (footprint overlap, baseline-to-depth ratio) and the disparity search ranges of the
matcher need the scene depth. The sparse points of the georeferencing step are used when the oriented
images carry them; otherwise (e.g. orientations from simulator truth or an external source) ORB
features are matched between spatially neighbouring images and triangulated with the known poses
(ORB rather than SIFT: ~15x faster here, and a few hundred points per image are all that is needed).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ProcessingError
from .camera_views import CameraView


@dataclass
class ViewDepth:
    depth_lo_m: float  # 2nd percentile of the depths of the sparse points seen by the view
    depth_med_m: float
    depth_hi_m: float  # 98th percentile
    ground_up_m: float  # median ENU up of those points
    n_points: int


@dataclass
class SparsePrior:
    xyz_enu_m: np.ndarray  # (N, 3)
    views: list[ViewDepth]
    source: str  # "oriented images" or "triangulated ORB features"

    def points_seen_by(self, view: CameraView) -> np.ndarray:
        uv, z = view.project_pinhole(self.xyz_enu_m)
        ok = (z > 0) & view.inside(uv)
        return self.xyz_enu_m[ok]


def nearest_neighbours(views: list[CameraView], k: int, max_axis_angle_deg: float = 45.0) -> list[tuple[int, int]]:
    """Unordered pairs (i < j) of each image with its k nearest camera centres (similar viewing direction)."""
    C = np.array([v.centre_enu_m for v in views])
    A = np.array([v.optical_axis_enu for v in views])
    d = np.linalg.norm(C[:, None] - C[None], axis=2)
    np.fill_diagonal(d, np.inf)
    cos_max = np.cos(np.radians(max_axis_angle_deg))
    pairs = set()
    for i in range(len(views)):
        taken = 0
        for j in np.argsort(d[i]):   # nearest first; stop at k (not a test of every image: images^2)
            if taken >= k or not np.isfinite(d[i, j]):
                break
            if A[i] @ A[j] >= cos_max:
                pairs.add((min(i, int(j)), max(i, int(j))))
                taken += 1
    return sorted(pairs)


def triangulate_features(views: list[CameraView], max_size: int = 1024, n_features: int = 2000,
                         k_neighbours: int = 4, max_reprojection_px: float = 2.0) -> np.ndarray:
    """Sparse ENU points from ORB feature matches between neighbouring images, triangulated with the known poses
    and kept when they reproject within ``max_reprojection_px`` in both images with a triangulation angle
    of at least 1 degree."""
    orb = cv2.ORB_create(nfeatures=n_features)
    feats = []
    small_views = []
    for v in views:
        s = min(1.0, max_size / max(v.width, v.height))
        sv = v.scaled(s) if s < 1.0 else v
        small_views.append(sv)
        kp, desc = orb.detectAndCompute(sv.read_image(gray=True), None)
        pts = np.array([p.pt for p in kp], np.float64).reshape(-1, 2)
        feats.append((pts, desc))
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    out = []
    for i, j in nearest_neighbours(views, k_neighbours):
        (pi, di), (pj, dj) = feats[i], feats[j]
        if di is None or dj is None or len(pi) < 8 or len(pj) < 8:
            continue
        knn = matcher.knnMatch(di, dj, k=2)
        m = np.array([(a.queryIdx, a.trainIdx) for a, *rest in knn if rest and a.distance < 0.8 * rest[0].distance],
                     int).reshape(-1, 2)
        if len(m) < 8:
            continue
        vi, vj = small_views[i], small_views[j]
        xi = vi.undistort_points(pi[m[:, 0]])
        xj = vj.undistort_points(pj[m[:, 1]])
        origin = vi.centre_enu_m
        Pi = np.hstack([vi.R_world_to_cam, (-vi.R_world_to_cam @ (vi.centre_enu_m - origin))[:, None]])
        Pj = np.hstack([vj.R_world_to_cam, (-vj.R_world_to_cam @ (vj.centre_enu_m - origin))[:, None]])
        Xh = cv2.triangulatePoints(Pi, Pj, xi.T.astype(np.float64), xj.T.astype(np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            X = (Xh[:3] / Xh[3]).T + origin
        ok = np.all(np.isfinite(X), axis=1)
        for v, x in ((vi, xi), (vj, xj)):
            pc = v.to_camera(X)
            with np.errstate(divide="ignore", invalid="ignore"):
                err = np.linalg.norm(pc[:, :2] / pc[:, 2:3] - x, axis=1) * v.focal_px
            ok &= (pc[:, 2] > 0) & (err < max_reprojection_px)
        ri = X - vi.centre_enu_m
        rj = X - vj.centre_enu_m
        with np.errstate(divide="ignore", invalid="ignore"):
            cosang = np.sum(ri * rj, axis=1) / (np.linalg.norm(ri, axis=1) * np.linalg.norm(rj, axis=1))
        ok &= cosang < np.cos(np.radians(1.0))
        out.append(X[ok])
    return np.concatenate(out) if out else np.zeros((0, 3))


class _PointsNear:
    """The sparse points a view may see, without projecting every point into every view (the points grow with
    the block, so that costs images^2: minutes at 1000 images). The points are sorted by east; a view's image
    pyramid, cut by the slab of the points' heights, lies in the box of its 4 corner rays' ends on the slab's
    two planes, and only the points in that box (a superset of those it sees: the caller's exact test decides)
    are returned, in their original order. A view that is not above the slab, or a corner ray that does not
    point down, gets every point (the exact test on all, as before)."""

    def __init__(self, xyz_enu_m: np.ndarray):
        self.xyz = xyz_enu_m
        self.order = np.argsort(xyz_enu_m[:, 0], kind="stable")
        self.east = xyz_enu_m[self.order, 0]
        self.z_lo = float(xyz_enu_m[:, 2].min()) if len(xyz_enu_m) else 0.0
        self.z_hi = float(xyz_enu_m[:, 2].max()) if len(xyz_enu_m) else 0.0

    def in_view(self, view: CameraView) -> np.ndarray:
        n = len(self.xyz)
        every = np.arange(n)
        c = np.asarray(view.centre_enu_m, float)
        if not n or not np.all(np.isfinite(c)) or c[2] <= self.z_hi:
            return every
        u = np.array([-0.5, view.width - 0.5, view.width - 0.5, -0.5])
        v = np.array([-0.5, -0.5, view.height - 0.5, view.height - 0.5])
        rays = view.rays_enu(u, v)
        if not np.all(np.isfinite(rays)) or np.any(rays[:, 2] >= 0):
            return every
        ends = np.concatenate([c + ((h - c[2]) / rays[:, 2])[:, None] * rays for h in (self.z_lo, self.z_hi)])
        pad = 1e-6 * (1.0 + np.abs(ends[:, :2]).max()) + 1e-3
        w, s = ends[:, 0].min() - pad, ends[:, 1].min() - pad
        e, nn = ends[:, 0].max() + pad, ends[:, 1].max() + pad
        a, b = np.searchsorted(self.east, w, side="left"), np.searchsorted(self.east, e, side="right")
        idx = self.order[a:b]
        y = self.xyz[idx, 1]
        return np.sort(idx[(y >= s) & (y <= nn)])


def build_sparse_prior(views: list[CameraView], sparse_xyz_enu_m: np.ndarray | None = None,
                       min_points: int = 200) -> SparsePrior:
    """Scene depths per view from the given sparse points (when at least ``min_points``), else from
    triangulated ORB matches."""
    source = "oriented images"
    xyz = None if sparse_xyz_enu_m is None else np.asarray(sparse_xyz_enu_m, float).reshape(-1, 3)
    if xyz is None or len(xyz) < min_points:
        xyz = triangulate_features(views)
        source = "triangulated ORB features"
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    if len(xyz) < 30:
        raise ProcessingError(f"cannot find the scene: only {len(xyz)} sparse points ({source}); the images do not "
                              "overlap or their orientations are wrong")
    # a global robust cut: points far outside the bulk of the scene (gross mismatches)
    med = np.median(xyz, axis=0)
    mad = np.median(np.abs(xyz - med), axis=0) * 1.4826 + 1e-6
    xyz = xyz[np.all(np.abs(xyz - med) < 12.0 * mad + 1.0, axis=1)]
    per_view = []
    all_lo = []
    near = _PointsNear(xyz)
    for v in views:
        sub = xyz[near.in_view(v)]   # a superset of the points the view sees, found without testing them all
        uv, z = v.project_pinhole(sub)
        ok = (z > 0) & v.inside(uv)
        if ok.sum() >= 10:
            zs = z[ok]
            lo, md, hi = np.percentile(zs, [2, 50, 98])
            per_view.append(ViewDepth(float(lo), float(md), float(hi), float(np.median(sub[ok, 2])), int(ok.sum())))
            all_lo.append((lo, md, hi))
        else:
            per_view.append(None)
    if not all_lo:
        raise ProcessingError("no sparse point projects into any image: the orientations are inconsistent")
    # views without enough points borrow the depth range of the scene seen from their own height
    ground = float(np.median(xyz[:, 2]))
    rel = np.median([(lo / md, hi / md) for lo, md, hi in all_lo], axis=0)
    for k, v in enumerate(views):
        if per_view[k] is None:
            md = max(1.0, float(v.centre_enu_m[2] - ground))
            per_view[k] = ViewDepth(md * rel[0], md, md * rel[1], ground, 0)
    return SparsePrior(xyz, per_view, source)
