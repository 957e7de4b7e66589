"""Frame camera, global shutter: pinhole with Brown-Conrady distortion (OpenCV's k1, k2, k3, p1, p2), or
an equidistant fisheye (OpenCV's fisheye model, k1..k4).

Conventions
-----------
* Camera frame: x right in the image, y down in the image, z along the optical axis (forward), as in
  OpenCV and COLMAP.
* Pixel coordinates (u, v): OpenCV's, the *centre* of the top-left pixel is (0, 0). COLMAP puts that
  centre at (0.5, 0.5): its principal point is (cx + 0.5, cy + 0.5) (``CameraModel.colmap_params``).
* Distortion acts on normalised coordinates ``x = X/Z, y = Y/Z``::

      r2 = x^2 + y^2,  radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
      xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
      yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
      u = fx xd + cx,  v = fy yd + cy

  which is OpenCV's model and COLMAP's ``FULL_OPENCV`` with k4 = k5 = k6 = 0.
* Fisheye (``projection="fisheye"``): the ray's angle from the axis theta = atan(r) is mapped to
  ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` and
  ``(xd, yd) = (theta_d / r) (x, y)``: OpenCV's ``cv2.fisheye`` and COLMAP's ``OPENCV_FISHEYE``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


@dataclass
class CameraOptions:
    width_px: int = 1600
    height_px: int = 1200
    sensor_width_mm: float = 7.04  # pixel pitch = sensor_width_mm / width_px (square pixels)
    focal_mm: float = 6.16
    principal_offset: tuple[float, float] = (0.0040, -0.0034)  # (cx, cy) offset from the image centre, in units of width
    k1: float = -0.118
    k2: float = 0.082
    k3: float = -0.012
    p1: float = 0.00062
    p2: float = -0.00041
    make: str = "GeorefSim"
    model: str = "SimCam-GS"
    projection: str = "perspective"  # or "fisheye" (then k1..k4 are the fisheye's, p1 = p2 = 0)
    k4: float = 0.0
    # rolling shutter: time from the first to the last row (s; 0 = global shutter); row v is exposed at
    # (v / height - 0.5) * readout_s from the exposure time (the middle row's)
    readout_s: float = 0.0

    def rolling(self, readout_s: float) -> "CameraOptions":
        """The same camera with a rolling shutter of this readout time (EXIF model SimCam-RS, which Georef's
        shutter table knows as rolling)."""
        from dataclasses import replace

        return replace(self, readout_s=float(readout_s), model="SimCam-RS" if readout_s > 0 else self.model)

    @classmethod
    def fisheye(cls) -> "CameraOptions":
        """A wide-angle action camera: equidistant fisheye, about 90 degrees across the image width
        (f = 1000 px at 1600 px wide; 1.8 times the default camera's footprint)."""
        return cls(focal_mm=4.4, principal_offset=(0.0030, -0.0025), k1=0.021, k2=-0.0062, k3=0.0011, p1=0.0, p2=0.0,
                   model="SimCam-FE", projection="fisheye", k4=-0.0002)

    def scaled(self, width_px: int, height_px: int) -> "CameraOptions":
        """The same optics (field of view, distortion) on a sensor with another pixel count."""
        from dataclasses import replace

        return replace(self, width_px=int(width_px), height_px=int(height_px))


@dataclass
class CameraModel:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    pixel_size_mm: float = 0.0044
    make: str = "GeorefSim"
    model: str = "SimCam-GS"
    projection: str = "perspective"
    k4: float = 0.0
    readout_s: float = 0.0           # rolling shutter (CameraOptions.readout_s); 0: global shutter

    def __post_init__(self):
        if self.projection not in ("perspective", "fisheye"):
            raise ValueError(f"camera projection {self.projection!r}: perspective or fisheye")

    @classmethod
    def from_options(cls, o: CameraOptions) -> "CameraModel":
        pix = o.sensor_width_mm / o.width_px
        f = o.focal_mm / pix
        return cls(width=o.width_px, height=o.height_px, fx=f, fy=f,
                   cx=(o.width_px - 1) / 2.0 + o.principal_offset[0] * o.width_px,
                   cy=(o.height_px - 1) / 2.0 + o.principal_offset[1] * o.width_px,
                   k1=o.k1, k2=o.k2, k3=o.k3, p1=o.p1, p2=o.p2, pixel_size_mm=pix, make=o.make, model=o.model,
                   projection=o.projection, k4=o.k4, readout_s=o.readout_s)

    @property
    def fisheye(self) -> bool:
        return self.projection == "fisheye"

    # ---- derived quantities ------------------------------------------------------------------
    @property
    def focal_mm(self) -> float:
        return self.fx * self.pixel_size_mm

    @property
    def sensor_size_mm(self) -> tuple[float, float]:
        return self.width * self.pixel_size_mm, self.height * self.pixel_size_mm

    @property
    def focal_35mm_equiv(self) -> float:
        w, h = self.sensor_size_mm
        return self.focal_mm * math.hypot(36.0, 24.0) / math.hypot(w, h)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def colmap_params(self) -> tuple[str, list[float]]:
        """COLMAP camera model name and parameter list (COLMAP pixel convention)."""
        if self.fisheye:
            return "OPENCV_FISHEYE", [self.fx, self.fy, self.cx + 0.5, self.cy + 0.5, self.k1, self.k2, self.k3, self.k4]
        return "FULL_OPENCV", [self.fx, self.fy, self.cx + 0.5, self.cy + 0.5, self.k1, self.k2, self.p1, self.p2,
                               self.k3, 0.0, 0.0, 0.0]

    def to_dict(self) -> dict:
        d = asdict(self)
        w, h = self.sensor_size_mm
        model, params = self.colmap_params()
        d.update({
            "pixel_convention": "OpenCV: centre of the top-left pixel is (0, 0); COLMAP adds 0.5",
            "camera_frame": "x right, y down (image), z forward along the optical axis",
            "distortion_model": ("OpenCV fisheye: theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)"
                                 if self.fisheye else
                                 "OpenCV/Brown: radial k1,k2,k3 + tangential p1,p2 on normalised coordinates"),
            "focal_mm": self.focal_mm, "sensor_width_mm": w, "sensor_height_mm": h,
            "focal_35mm_equiv": self.focal_35mm_equiv, "K": self.K.tolist(),
            "colmap_model": model, "colmap_params": params,
        })
        return d

    # ---- distortion -----------------------------------------------------------------------------
    def distort_normalized(self, x, y):
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if self.fisheye:
            r = np.hypot(x, y)
            theta = np.arctan(r)
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(r > 1e-12, self._theta_d(theta) / r, 1.0)
            return x * scale, y * scale
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * radial + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return xd, yd

    def _theta_d(self, theta):
        t2 = theta * theta
        return theta * (1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4))))

    def undistort_normalized(self, xd, yd, iterations: int = 8):
        """Inverse of :meth:`distort_normalized` by Newton's method (to ~1e-12 in normalised units)."""
        xd = np.asarray(xd, dtype=float)
        yd = np.asarray(yd, dtype=float)
        if self.fisheye:
            theta_d = np.hypot(xd, yd)
            theta = theta_d.copy()
            for _ in range(2 * iterations):
                t2 = theta * theta
                d = 1.0 + t2 * (3 * self.k1 + t2 * (5 * self.k2 + t2 * (7 * self.k3 + 9 * t2 * self.k4)))
                theta = theta - (self._theta_d(theta) - theta_d) / d
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(theta_d > 1e-12, np.tan(theta) / theta_d, 1.0)
            return xd * scale, yd * scale
        x, y = xd.copy(), yd.copy()
        k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)
            fx_ = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
            fy_ = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
            a = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            b = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            c = b
            d = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
            det = a * d - b * c
            x = x - (d * fx_ - b * fy_) / det
            y = y - (-c * fx_ + a * fy_) / det
        return x, y

    # ---- projection --------------------------------------------------------------------------------
    def max_field_radius(self) -> float:
        """Largest undistorted normalised radius seen by the image (at its corners and edge midpoints)."""
        u = np.array([0, self.width - 1, 0, self.width - 1, (self.width - 1) / 2, (self.width - 1) / 2, 0, self.width - 1])
        v = np.array([0, 0, self.height - 1, self.height - 1, 0, self.height - 1, (self.height - 1) / 2, (self.height - 1) / 2])
        x, y = self.undistort_normalized((u - self.cx) / self.fx, (v - self.cy) / self.fy)
        return float(np.max(np.hypot(x, y)))

    def project(self, points_cam) -> np.ndarray:
        """Camera-frame points (..., 3) to distorted pixel coordinates (..., 2); NaN behind the camera and
        outside the field of view (the distortion polynomial folds far-off rays back into the image,
        which the lens does not)."""
        p = np.asarray(points_cam, dtype=float)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inside = (z > 0) & (np.hypot(p[..., 0], p[..., 1]) <= 1.02 * self.max_field_radius() * z)
            x = np.where(inside, p[..., 0] / z, np.nan)
            y = np.where(inside, p[..., 1] / z, np.nan)
        xd, yd = self.distort_normalized(x, y)
        return np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=-1)

    def project_world(self, points_world, centre_world, R_cam_to_world) -> np.ndarray:
        """World points (N, 3) seen from a camera at ``centre_world`` with attitude ``R_cam_to_world``."""
        pc = (np.asarray(points_world, dtype=float) - np.asarray(centre_world, dtype=float)) @ np.asarray(R_cam_to_world)
        return self.project(pc)

    def row_time_s(self, v) -> np.ndarray:
        """Exposure time of image row(s) ``v`` (OpenCV pixel rows) from the image's exposure time, which is the
        middle row's: 0 for a global shutter."""
        return self.readout_s * (np.asarray(v, dtype=float) / self.height - 0.5)

    def project_world_moving(self, points_world, centre_world, R_cam_to_world, velocity_world) -> np.ndarray:
        """project_world for a camera moving at ``velocity_world`` (m/s) through a rolling-shutter readout: each
        point is seen from where the camera was when the point's row was exposed (a fixed point in the row,
        converged in a few steps: the row moves by a small fraction of the image while the camera moves).
        The rotation during the readout is neglected."""
        pts = np.asarray(points_world, dtype=float)
        uv = self.project_world(pts, centre_world, R_cam_to_world)
        if self.readout_s <= 0:
            return uv
        for _ in range(4):
            t = self.row_time_s(np.nan_to_num(uv[:, 1], nan=0.5 * self.height))
            uv = self.project((pts - np.asarray(centre_world, float) - t[:, None] * np.asarray(velocity_world, float))
                              @ np.asarray(R_cam_to_world))
        return uv

    def pixel_to_ray(self, u, v) -> np.ndarray:
        """Unit camera-frame directions through pixel positions (distortion removed)."""
        x, y = self.undistort_normalized((np.asarray(u, dtype=float) - self.cx) / self.fx,
                                         (np.asarray(v, dtype=float) - self.cy) / self.fy)
        d = np.stack([x, y, np.ones_like(x)], axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def pixel_rays(self) -> np.ndarray:
        """(height, width, 3) unit camera-frame directions through every pixel centre."""
        u, v = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
        return self.pixel_to_ray(u, v)

    def footprint_m(self, distance_m: float) -> tuple[float, float]:
        """Ground footprint (width, height) of a nadir image at a distance: for the perspective camera
        ignoring distortion; for the fisheye between the undistorted edge midpoints (the pinhole size
        of a fisheye understates its coverage several times)."""
        if self.fisheye:
            cu, cv = (self.width - 1) / 2.0, (self.height - 1) / 2.0
            x, _ = self.undistort_normalized((np.array([0.0, self.width - 1.0]) - self.cx) / self.fx, (cv - self.cy) / self.fy)
            _, y = self.undistort_normalized((cu - self.cx) / self.fx, (np.array([0.0, self.height - 1.0]) - self.cy) / self.fy)
            return float(distance_m * (x[1] - x[0])), float(distance_m * (y[1] - y[0]))
        return distance_m * self.width / self.fx, distance_m * self.height / self.fy
