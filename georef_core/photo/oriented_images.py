"""Oriented images: the hand-over from georeferencing to dense reconstruction and orthophotos.

``oriented_images.json`` (format ``georef-oriented-images/1``) holds, in plain JSON:

* ``project_frame``: :class:`georef_core.project_frame.ProjectFrame` (project CRS EPSG, origin); camera
  poses are expressed in its **local ENU** frame (Euclidean, metres), products are reported in the
  project CRS (E, N, ellipsoidal h) through the frame's conversions.
* ``image_dir``: folder of the images (absolute, or relative to the JSON file).
* ``cameras``: id -> COLMAP camera model name, width, height and parameters (COLMAP conventions:
  pixel centres at +0.5, the OPENCV model's fx fy cx cy k1 k2 p1 p2, ...), and ``readout_s`` for a
  rolling-shutter camera whose readout the adjustment modelled.
* ``images``: name, camera id, ``R_cam_to_enu`` (3x3, camera axes x right / y down / z forward into
  ENU) and ``centre_enu_m`` (the camera at the image's time, its middle row's exposure), with optional
  ``centre_sigma_enu_m`` and ``velocity_enu_m_s`` (rolling shutter: row v was seen from
  ``centre + velocity (v / height - 0.5) readout_s``).
* ``sparse_points_file`` (optional): an ``.npz`` with ``xyz_enu_m`` (N, 3) and ``rgb`` (N, 3) uint8.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from ..project_frame import ProjectFrame

FORMAT = "georef-oriented-images/1"


@dataclass
class OrientedCamera:
    model: str
    width: int
    height: int
    params: list[float]
    readout_s: float = 0.0  # rolling shutter: first to last row (s); row v exposed (v / height - 0.5) readout_s
                            # after the image's time, from centre + velocity * that time; 0: global shutter

    def K(self) -> np.ndarray:
        """3x3 calibration matrix in OpenCV pixel convention (centre of the top-left pixel at 0, 0)."""
        p = self.params
        if self.model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
            fx = fy = p[0]
            cx, cy = p[1], p[2]
        else:
            fx, fy, cx, cy = p[0], p[1], p[2], p[3]
        return np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])

    def opencv_distortion(self) -> np.ndarray:
        """Distortion coefficients (k1, k2, p1, p2, k3) for cv2 (zeros where the model has none)."""
        p = self.params
        m = self.model
        if m in ("SIMPLE_PINHOLE", "PINHOLE"):
            return np.zeros(5)
        if m == "SIMPLE_RADIAL":
            return np.array([p[3], 0.0, 0.0, 0.0, 0.0])
        if m == "RADIAL":
            return np.array([p[3], p[4], 0.0, 0.0, 0.0])
        if m == "OPENCV":
            return np.array([p[4], p[5], p[6], p[7], 0.0])
        if m == "FULL_OPENCV":
            return np.array([p[4], p[5], p[6], p[7], p[8]])
        raise ValueError(f"camera model {m} has no OpenCV pinhole distortion equivalent")


@dataclass
class OrientedImage:
    name: str
    camera_id: int
    R_cam_to_enu: np.ndarray
    centre_enu_m: np.ndarray
    centre_sigma_enu_m: np.ndarray | None = None
    velocity_enu_m_s: np.ndarray | None = None  # the camera's velocity (rolling shutter; None: not known)

    def projection_matrix(self, camera: OrientedCamera) -> np.ndarray:
        """3x4 P = K [R | t] mapping ENU points to undistorted pixel coordinates (OpenCV convention)."""
        R = self.R_cam_to_enu.T
        t = -R @ self.centre_enu_m
        return camera.K() @ np.hstack([R, t[:, None]])


@dataclass
class OrientedImages:
    frame: ProjectFrame
    image_dir: Path
    cameras: dict[int, OrientedCamera]
    images: list[OrientedImage]
    sparse_xyz_enu_m: np.ndarray | None = None
    sparse_rgb: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def image_path(self, image: OrientedImage) -> Path:
        return self.image_dir / image.name

    def write(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        doc = {
            "format": FORMAT,
            "project_frame": self.frame.to_dict(),
            "image_dir": str(self.image_dir),
            "cameras": {str(k): {"model": c.model, "width": int(c.width), "height": int(c.height),
                                 "params": [float(v) for v in c.params],
                                 **({"readout_s": float(c.readout_s)} if c.readout_s else {})}
                        for k, c in self.cameras.items()},
            "images": [{
                "name": im.name, "camera_id": int(im.camera_id),
                "R_cam_to_enu": np.asarray(im.R_cam_to_enu, float).tolist(),
                "centre_enu_m": [float(v) for v in im.centre_enu_m],
                **({"centre_sigma_enu_m": [float(v) for v in im.centre_sigma_enu_m]}
                   if im.centre_sigma_enu_m is not None else {}),
                **({"velocity_enu_m_s": [float(v) for v in im.velocity_enu_m_s]}
                   if im.velocity_enu_m_s is not None else {}),
            } for im in self.images],
            **self.extra,
        }
        if self.sparse_xyz_enu_m is not None:
            sp = path.with_name(path.stem + "_sparse.npz")
            rgb = self.sparse_rgb if self.sparse_rgb is not None else np.zeros_like(self.sparse_xyz_enu_m, np.uint8)
            np.savez_compressed(sp, xyz_enu_m=self.sparse_xyz_enu_m, rgb=rgb)
            doc["sparse_points_file"] = sp.name
        # the images' folder also relative to this file's: a platform worker materialises the survey and the
        # run's outputs side by side in a folder of its own (runs/<run>/survey, .../out; a part's in
        # parts/<step>-<k>/), so a later run or part, or another machine, finds its own copy of the images
        # where the absolute path (the georef run's folder) is gone
        if self.image_dir.is_absolute():
            try:
                doc["image_dir_relative"] = os.path.relpath(self.image_dir, path.parent.resolve())
            except ValueError:   # another drive (Windows): the absolute path only
                pass
        path.write_text(json.dumps(doc, indent=1))
        return path


def read_oriented_images(path) -> OrientedImages:
    """Read ``oriented_images.json``; errors name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "oriented-images file not found")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"not valid JSON ({exc})") from None
    if doc.get("format") != FORMAT:
        raise InputFileError(path, f"not an oriented-images file (format {doc.get('format')!r}, expected {FORMAT!r})")
    try:
        frame = ProjectFrame.from_dict(doc["project_frame"])
        image_dir = Path(doc["image_dir"])
        if not image_dir.is_absolute():
            image_dir = (path.parent / image_dir).resolve()
        rel = doc.get("image_dir_relative")
        if isinstance(rel, str) and rel and (path.parent / rel).is_dir():
            image_dir = (path.parent / rel).resolve()
        cameras = {int(k): OrientedCamera(v["model"], int(v["width"]), int(v["height"]), list(map(float, v["params"])),
                                          float(v.get("readout_s", 0.0)))
                   for k, v in doc["cameras"].items()}
        images = []
        for im in doc["images"]:
            sig, vel = im.get("centre_sigma_enu_m"), im.get("velocity_enu_m_s")
            images.append(OrientedImage(im["name"], int(im["camera_id"]), np.asarray(im["R_cam_to_enu"], float),
                                        np.asarray(im["centre_enu_m"], float),
                                        None if sig is None else np.asarray(sig, float),
                                        None if vel is None else np.asarray(vel, float).reshape(3)))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputFileError(path, f"malformed oriented-images file ({exc!r})") from None
    for im in images:
        if im.camera_id not in cameras:
            raise InputFileError(path, f"image {im.name} refers to unknown camera {im.camera_id}")
    xyz = rgb = None
    if doc.get("sparse_points_file"):
        sp = path.parent / doc["sparse_points_file"]
        if sp.is_file():
            with np.load(sp) as z:
                xyz, rgb = z["xyz_enu_m"], z["rgb"]
    known = {"format", "project_frame", "image_dir", "image_dir_relative", "cameras", "images", "sparse_points_file"}
    extra = {k: v for k, v in doc.items() if k not in known}
    return OrientedImages(frame, image_dir, cameras, images, xyz, rgb, extra)


def oriented_images_from_simulator_truth(survey_dir) -> OrientedImages:
    """The true orientation of a simulated survey (``truth/camera_poses.json`` + ``intrinsics.json``),
    for testing the steps after georeferencing against truth."""
    survey_dir = Path(survey_dir)
    poses = json.loads((survey_dir / "truth" / "camera_poses.json").read_text())
    intr = json.loads((survey_dir / "truth" / "intrinsics.json").read_text())
    frame = ProjectFrame.from_dict(poses["site_frame"])

    def camera(d: dict) -> OrientedCamera:
        return OrientedCamera(d["colmap_model"], int(d["width"]), int(d["height"]), list(map(float, d["colmap_params"])),
                              float(d.get("readout_s", 0.0)))

    cameras, camera_of = {1: camera(intr)}, {}
    several = survey_dir / "truth" / "cameras.json"     # a survey simulated with a second camera
    if several.is_file():
        doc = json.loads(several.read_text())
        cameras = {int(k): camera(json.loads((survey_dir / "truth" / v).read_text())) for k, v in doc["cameras"].items()}
        camera_of = {k: int(v) for k, v in doc["images"].items()}
    images = [OrientedImage(p["name"], camera_of.get(p["name"], 1), np.asarray(p["R_cam_to_enu"], float),
                            np.asarray(p["camera_centre_enu_m"], float),
                            velocity_enu_m_s=None if "camera_velocity_enu_m_s" not in p
                            else np.asarray(p["camera_velocity_enu_m_s"], float))
              for p in poses["images"]]
    return OrientedImages(frame, survey_dir / "images", cameras, images, extra={"source": "simulator truth"})
