"""An oriented image as a view at a working scale: pinhole calibration scaled to the image size used,
lens distortion (OpenCV coefficients, scale-free), rotation world(ENU)->camera and projection centre.

Pixel convention: OpenCV, the centre of the top-left pixel is (0, 0). Scaling an image by ``s`` maps a
pixel ``u`` to ``s (u + 0.5) - 0.5``. Camera axes: x right, y down, z forward (into the scene).

A rolling-shutter image (its camera's readout time and velocity known, oriented_images.py) is read as the
image a global shutter would have taken from the view's centre: each pixel is taken from where the point
at the scene's depth appeared in the real image, whose row was exposed from ``centre + velocity t(row)``
(``global_shutter_maps``). Everything downstream (rectification, fusion, orthophoto) then sees a central
camera. The depth is one per image (the sparse points' median): relief of a fraction q of the flying
height leaves q of the correction (a few pixels at most) uncorrected.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ..adjustment.camera_model import brown_distortion, fisheye_radius
from ..errors import InputFileError
from ..photo.oriented_images import OrientedCamera, OrientedImages

SUPPORTED_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE")
FISHEYE_MODELS = ("OPENCV_FISHEYE",)


def opencv_distortion_coeffs(camera: OrientedCamera) -> np.ndarray:
    """OpenCV distortion vector of a COLMAP camera: (k1, k2, p1, p2, k3) or, for FULL_OPENCV with rational
    terms, (k1, k2, p1, p2, k3, k4, k5, k6); for OPENCV_FISHEYE cv2.fisheye's (k1, k2, k3, k4)."""
    if camera.model == "OPENCV_FISHEYE":
        return np.array([float(v) for v in camera.params[4:8]])
    if camera.model == "FULL_OPENCV":
        p = list(camera.params) + [0.0] * 12
        coeffs = np.array(p[4:12], float)
        return coeffs if np.any(coeffs[5:] != 0.0) else coeffs[:5]
    return np.asarray(camera.opencv_distortion(), float)


@dataclass
class CameraView:
    """One image at a working scale."""

    name: str
    path: Path
    width: int
    height: int
    K: np.ndarray  # 3x3, at this scale
    dist: np.ndarray  # OpenCV distortion coefficients (independent of the scale)
    R_world_to_cam: np.ndarray  # 3x3, x_cam = R (x_enu - C)
    centre_enu_m: np.ndarray  # 3
    full_width: int
    full_height: int
    fisheye: bool = False  # dist is cv2.fisheye's (k1..k4 on the ray angle) instead of the pinhole model's
    # rolling shutter: readout (s, first to last row), camera velocity (ENU, m/s) and the scene depth used to
    # read the image as a global shutter's; all three needed (else the image is read as it is)
    readout_s: float = 0.0
    velocity_enu_m_s: np.ndarray | None = None
    scene_depth_m: float | None = None

    @property
    def rolling_shutter(self) -> bool:
        return self.readout_s > 0 and self.velocity_enu_m_s is not None

    # --- geometry --------------------------------------------------------------------------------
    @property
    def optical_axis_enu(self) -> np.ndarray:
        return self.R_world_to_cam[2].copy()

    @property
    def focal_px(self) -> float:
        return float(0.5 * (self.K[0, 0] + self.K[1, 1]))

    def scaled_to(self, width: int, height: int) -> "CameraView":
        """The same view with the image resampled to width x height pixels."""
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return replace(self, width=int(width), height=int(height), K=K)

    def scaled(self, factor: float) -> "CameraView":
        return self.scaled_to(max(1, round(self.width * factor)), max(1, round(self.height * factor)))

    def to_camera(self, xyz_enu: np.ndarray) -> np.ndarray:
        """ENU points (N, 3) -> camera coordinates (N, 3) (a transposed view of a (3, N) array: the
        (3, 3) @ (3, N) product is several times faster than (N, 3) @ (3, 3) in numpy)."""
        return (self.R_world_to_cam @ (np.asarray(xyz_enu, float) - self.centre_enu_m).T).T

    def project_pinhole(self, xyz_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted (pinhole) pixel coordinates (N, 2) and depths z (N,) of ENU points."""
        pc = self.to_camera(xyz_enu)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = pc[:, :2] / z[:, None]
        uv = uv * np.array([self.K[0, 0], self.K[1, 1]]) + np.array([self.K[0, 2], self.K[1, 2]])
        return uv, z

    def project_distorted(self, xyz_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates in the real (distorted) image (N, 2) and depths z (N,) of ENU points."""
        pc = self.to_camera(xyz_enu)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = pc[:, 0] / z
            y = pc[:, 1] / z
        xd, yd = (apply_fisheye_distortion if self.fisheye else apply_distortion)(x, y, self.dist)
        uv = np.stack([self.K[0, 0] * xd + self.K[0, 2], self.K[1, 1] * yd + self.K[1, 2]], axis=1)
        return uv, z

    def rays_enu(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """ENU directions (N, 3) of pinhole pixels, scaled so that their camera-z component is 1
        (a point at depth z is ``C + z * ray``)."""
        x = (np.asarray(u, float) - self.K[0, 2]) / self.K[0, 0]
        y = (np.asarray(v, float) - self.K[1, 2]) / self.K[1, 1]
        d = np.stack([x, y, np.ones_like(x)], axis=-1)
        return d @ self.R_world_to_cam

    def inside(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        return ((uv[:, 0] >= -0.5 + margin) & (uv[:, 0] <= self.width - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin) & (uv[:, 1] <= self.height - 0.5 - margin))

    # --- pixels ----------------------------------------------------------------------------------
    def read_image(self, gray: bool = False) -> np.ndarray:
        """The image file at this view's scale (BGR uint8, or grey); a rolling-shutter image as a global
        shutter's (module docstring) once ``scene_depth_m`` is known."""
        img = read_image_at(self.path, self.full_width, self.full_height, self.width, self.height, gray)
        if self.rolling_shutter and self.scene_depth_m:
            mx, my = global_shutter_maps(self)
            img = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return img

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Pixels of the real (distorted) image (N, 2) -> undistorted normalised coordinates x/z, y/z (N, 2)."""
        pts = np.asarray(uv, np.float64).reshape(-1, 1, 2)
        if self.fisheye:
            return cv2.fisheye.undistortPoints(pts, self.K, self.dist).reshape(-1, 2)
        return cv2.undistortPoints(pts, self.K, self.dist).reshape(-1, 2)

    def rectify_maps(self, R: np.ndarray, K_new: np.ndarray, size: tuple[int, int], map_type=cv2.CV_32FC1):
        """cv2.remap maps from this (distorted) view's pixels to a pinhole grid with calibration ``K_new``,
        ``size`` (width, height) and the rotation ``R`` from this camera's axes to the new one's."""
        if self.fisheye:
            return cv2.fisheye.initUndistortRectifyMap(self.K, self.dist, R, K_new, size, map_type)
        return cv2.initUndistortRectifyMap(self.K, self.dist, R, K_new, size, map_type)

    def undistort_maps(self, pinhole: "CameraView", R_rect: np.ndarray | None = None):
        """cv2.remap maps from this (distorted) view's pixels to the pinhole grid ``pinhole`` (same centre;
        its own K, size and, when given, the rotation R_rect from this camera's axes to ``pinhole``'s)."""
        R = np.eye(3) if R_rect is None else R_rect
        return self.rectify_maps(R, pinhole.K, (pinhole.width, pinhole.height))


def global_shutter_maps(view: CameraView) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps (float32, at the view's scale) from a rolling-shutter image to the image a global
    shutter would have taken from ``view.centre_enu_m`` (the middle row's camera centre), for a scene at
    camera depth ``view.scene_depth_m``. A point at depth Z seen at pixel (u, v) from the centre was seen
    from the centre + a (a = velocity t, t the time of its row in the real image, camera axes) at
    (u, v) + f (-a_xy + (x, y) a_z) / Z to first order; the row is found in two steps."""
    w, h = view.width, view.height
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    fx, fy, cx, cy = (np.float32(view.K[0, 0]), np.float32(view.K[1, 1]), np.float32(view.K[0, 2]),
                      np.float32(view.K[1, 2]))
    x, y = (u - cx) / fx, (v - cy) / fy
    vel_cam = (view.R_world_to_cam @ np.asarray(view.velocity_enu_m_s, float)).astype(np.float32)
    rows_scale = np.float32(view.full_height / view.height)
    z = np.float32(view.scene_depth_m)

    def shift(row):
        full_row = (row + np.float32(0.5)) * rows_scale - np.float32(0.5)
        t = np.float32(view.readout_s) * (full_row / np.float32(view.full_height) - np.float32(0.5))
        ax, ay, az = vel_cam[0] * t, vel_cam[1] * t, vel_cam[2] * t
        return fx * (x * az - ax) / z, fy * (y * az - ay) / z

    _, dv = shift(v)
    du, dv = shift(v + dv)
    return u + du, v + dv


def apply_distortion(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV (Brown + optional rational) distortion of normalised coordinates; `dist` in OpenCV's order
    (k1, k2, p1, p2, k3, k4, k5, k6), shorter vectors padded with zeros."""
    d = np.zeros(8)
    d[: len(dist)] = dist
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    return brown_distortion(x, y, k1, k2, k3, p1, p2, (k4, k5, k6))


def apply_fisheye_distortion(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cv2.fisheye distortion of normalised coordinates: the ray angle theta = atan(r) becomes the radius
    theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)."""
    k1, k2, k3, k4 = (list(dist) + [0.0] * 4)[:4]
    r = np.hypot(x, y)
    theta_d = fisheye_radius(np.arctan(r), k1, k2, k3, k4)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(r > 1e-12, theta_d / r, 1.0)
    return x * scale, y * scale


def read_image_at(path: Path, full_width: int, full_height: int, width: int, height: int,
                  gray: bool = False) -> np.ndarray:
    flags = (cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR) | cv2.IMREAD_IGNORE_ORIENTATION
    img = cv2.imread(str(path), flags)
    if img is None:
        if not Path(path).is_file():
            raise InputFileError(path, "image file not found")
        raise InputFileError(path, "cannot read the image (not a JPEG/TIFF/PNG image or corrupt)")
    if img.shape[1] != full_width or img.shape[0] != full_height:
        raise InputFileError(path, f"image is {img.shape[1]} x {img.shape[0]} px but its camera says "
                                   f"{full_width} x {full_height}")
    if (width, height) != (full_width, full_height):
        img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    return img


def views_from_oriented(oriented: OrientedImages, max_image_size: int | None, source=None) -> list[CameraView]:
    """Views of all oriented images, each scaled so that its longer side is at most ``max_image_size``
    (never enlarged). ``source`` names the oriented-images file in errors."""
    views = []
    for im in oriented.images:
        cam = oriented.cameras[im.camera_id]
        if cam.model not in SUPPORTED_MODELS:
            raise InputFileError(source or oriented.image_dir,
                                 f"camera model {cam.model} of image {im.name} is not supported by the dense step "
                                 f"(supported: {', '.join(SUPPORTED_MODELS)})")
        R = np.asarray(im.R_cam_to_enu, float).T
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputFileError(source or oriented.image_dir, f"image {im.name}: R_cam_to_enu is not a rotation")
        v = CameraView(im.name, oriented.image_path(im), cam.width, cam.height, cam.K(),
                       opencv_distortion_coeffs(cam), R, np.asarray(im.centre_enu_m, float),
                       cam.width, cam.height, fisheye=cam.model in FISHEYE_MODELS, readout_s=float(cam.readout_s),
                       velocity_enu_m_s=im.velocity_enu_m_s)
        s = 1.0 if not max_image_size else min(1.0, max_image_size / max(cam.width, cam.height))
        views.append(v.scaled(s) if s < 1.0 else v)
    return views
