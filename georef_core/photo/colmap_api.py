"""The only module of Georef that imports pycolmap.

pycolmap's Python API moves between releases (option classes renamed or split, functions gaining or
losing arguments, properties becoming methods). Everything else in Georef talks to COLMAP through the
thin functions here and gets plain dataclasses / numpy arrays back, so that a pycolmap upgrade touches
this file only. Written against pycolmap 4.2 with fallbacks for the 3.10-3.12 names where met.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pycolmap

PYCOLMAP_VERSION = getattr(pycolmap, "__version__", "unknown")

CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE")


# ----------------------------------------------------------------------------- plain result types

@dataclass
class CameraData:
    camera_id: int
    model: str
    width: int
    height: int
    params: list[float]
    param_names: list[str]


@dataclass
class ImageData:
    image_id: int
    name: str
    camera_id: int
    R_cam_from_world: np.ndarray  # 3x3, x_cam = R x_world + t
    t_cam_from_world: np.ndarray  # 3
    centre: np.ndarray  # projection centre in the model frame, -R^T t
    num_points3D: int


@dataclass
class ReconstructionData:
    cameras: dict[int, CameraData]
    images: dict[int, ImageData]
    points_xyz: np.ndarray  # (N, 3)
    points_rgb: np.ndarray  # (N, 3) uint8
    points_error_px: np.ndarray  # (N,)
    points_track_length: np.ndarray  # (N,) int
    mean_reprojection_error_px: float
    mean_track_length: float
    # the observations (tracks): one row per (image, 3-D point) measurement
    obs_image_id: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    obs_point_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # row in points_xyz
    obs_xy_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # COLMAP pixels (top-left corner = 0, 0)

    @property
    def num_registered(self) -> int:
        return len(self.images)

    def image_by_name(self) -> dict[str, ImageData]:
        return {im.name: im for im in self.images.values()}


@dataclass
class MappingOutput:
    models: list  # opaque pycolmap.Reconstruction objects, largest first
    best: ReconstructionData | None
    model_sizes: list[int] = field(default_factory=list)


# ----------------------------------------------------------------------------- helpers

def _set_first(obj, names: Sequence[str], value) -> bool:
    """Set the first attribute of `names` that the object has (renamed options)."""
    for name in names:
        if hasattr(obj, name):
            try:
                setattr(obj, name, value)
                return True
            except (AttributeError, TypeError):
                continue
    return False


def _device(use_gpu: bool):
    dev = getattr(pycolmap, "Device", None)
    if dev is None:
        return None
    return dev.cuda if use_gpu else dev.cpu


def _call(fn, *args, device=None, **kwargs):
    """Call a pycolmap function, passing `device` only where the release accepts it."""
    if device is not None:
        try:
            return fn(*args, device=device, **kwargs)
        except TypeError:
            pass
    return fn(*args, **kwargs)


def _matrix(rotation) -> np.ndarray:
    m = rotation.matrix
    return np.asarray(m() if callable(m) else m, dtype=float)


def _cam_from_world(image):
    p = image.cam_from_world
    return p() if callable(p) else p


# ----------------------------------------------------------------------------- database

def open_database(path, fresh: bool = False):
    """Open (create) a COLMAP database; `fresh` deletes an existing file first. Returns the handle
    (close it with `close_database`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if fresh and path.exists():
        path.unlink()
    if hasattr(pycolmap.Database, "open"):
        return pycolmap.Database.open(str(path))
    return pycolmap.Database(str(path))  # 3.x


def close_database(db) -> None:
    if db is not None and hasattr(db, "close"):
        db.close()


def database_counts(database_path) -> dict:
    db = open_database(database_path)
    try:
        return {"images": int(db.num_images()), "cameras": int(db.num_cameras()),
                "keypoints": int(db.num_keypoints()), "matched_pairs": int(db.num_matched_image_pairs()),
                "verified_pairs": int(db.num_verified_image_pairs()),
                "pose_priors": int(db.num_pose_priors()) if hasattr(db, "num_pose_priors") else 0}
    finally:
        close_database(db)


def database_image_ids(database_path) -> dict[str, int]:
    db = open_database(database_path)
    try:
        return {im.name: int(im.image_id) for im in db.read_all_images()}
    finally:
        close_database(db)


# Where the COLMAP database holds an image id (4.x and 3.x schemas): table, column, and the column telling
# the sensor type where that column holds other sensors' ids too (images are sensor type 0).
_IMAGE_ID_COLUMNS = (("images", "image_id", None), ("keypoints", "image_id", None),
                     ("descriptors", "image_id", None), ("frame_data", "data_id", "sensor_type"),
                     ("pose_priors", "corr_data_id", "corr_sensor_type"), ("pose_priors", "image_id", None))


def _renumber(con, table: str, column: str, new_of: dict[int, int], type_column: str | None) -> None:
    """Apply an id permutation to one column: shift everything out of the way first, then map (a
    permutation applied in place would collide with unique keys)."""
    only = f" AND {type_column} = 0" if type_column else ""
    offset = int(con.execute(f"SELECT MAX({column}) FROM {table}").fetchone()[0] or 0) + 1
    con.execute(f"UPDATE {table} SET {column} = {column} + ? WHERE {column} IN "
                f"({','.join(str(int(k)) for k in new_of)}){only}", (offset,))
    con.executemany(f"UPDATE {table} SET {column} = ? WHERE {column} = ?{only}",
                    [(new, old + offset) for old, new in new_of.items()])


def number_images_by_name(database_path) -> bool:
    """Renumber the images of a freshly extracted database so that image ids follow the image names.

    COLMAP's extractor numbers images in the order its threads finish them, which changes from run to run
    with more than one thread; matching and mapping break ties by id, so the same photos gave slightly
    different models each run. Called between extraction and matching (a database with matches is
    refused: their pair ids would need recomputing). Frames of one image each (COLMAP 4) are renumbered in
    the same name order within each rig (COLMAP makes one rig per camera). Returns whether anything changed."""
    import sqlite3

    con = sqlite3.connect(str(database_path))
    try:
        columns = {t: {r[1] for r in con.execute(f"PRAGMA table_info({t})")}
                   for (t,) in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall()}
        for t in ("matches", "two_view_geometries"):
            if t in columns and con.execute(f"SELECT COUNT(*) FROM {t}").fetchone()[0]:
                raise ValueError(f"{database_path}: images can only be renumbered before matching")
        rows = con.execute("SELECT image_id, name FROM images").fetchall()
        ids = sorted(i for i, _ in rows)
        new_of = {old: new for (old, _), new in zip(sorted(rows, key=lambda r: r[1]), ids) if old != new}
        frame_new_of = {}
        if {"frame_data", "frames"} <= columns.keys():
            frames = con.execute("SELECT d.frame_id, MIN(d.data_id), COUNT(*), MAX(d.sensor_type), f.rig_id "
                                 "FROM frame_data d JOIN frames f ON f.frame_id = d.frame_id "
                                 "GROUP BY d.frame_id").fetchall()
            if frames and all(n == 1 and kind == 0 for _, _, n, kind, _ in frames):
                # within each rig (one per camera: several cameras, several rigs), frames in image-name order
                name_of = dict(rows)
                rigs: dict[int, list] = {}
                for f in frames:
                    rigs.setdefault(f[4], []).append(f)
                for rig_frames in rigs.values():
                    by_name = sorted(rig_frames, key=lambda f: name_of.get(f[1], ""))
                    frame_ids = sorted(f[0] for f in rig_frames)
                    frame_new_of.update({f[0]: new for f, new in zip(by_name, frame_ids) if f[0] != new})
        if not new_of and not frame_new_of:
            return False
        with con:
            if new_of:
                for table, column, type_column in _IMAGE_ID_COLUMNS:
                    if column in columns.get(table, ()) and (type_column is None or type_column in columns[table]):
                        _renumber(con, table, column, new_of, type_column)
            if frame_new_of:
                _renumber(con, "frame_data", "frame_id", frame_new_of, None)
        return True
    finally:
        con.close()


def write_position_priors(database_path, positions: dict[str, Sequence[float]]) -> int:
    """Replace the database's pose priors by Cartesian (metric, local frame) image positions, used by the
    spatial matcher. `positions`: image name -> (x, y, z). Returns the number written."""
    db = open_database(database_path)
    n = 0
    try:
        if hasattr(db, "clear_pose_priors"):
            db.clear_pose_priors()
        cartesian = pycolmap.PosePriorCoordinateSystem.CARTESIAN
        for im in db.read_all_images():
            if im.name not in positions:
                continue
            pos = np.asarray(positions[im.name], dtype=float).reshape(3, 1)
            prior = pycolmap.PosePrior()
            prior.position = pos
            prior.coordinate_system = cartesian
            if hasattr(prior, "corr_data_id"):  # 4.x: priors attach to a sensor datum
                prior.corr_data_id = im.data_id
                db.write_pose_prior(prior)
            else:  # 3.x: one prior per image id
                db.write_pose_prior(im.image_id, prior)
            n += 1
    finally:
        close_database(db)
    return n


# ----------------------------------------------------------------------------- extraction

def extract_sift(database_path, image_dir, image_names: Sequence[str] | None = None,
                 camera_model: str = "SIMPLE_RADIAL", single_camera: bool = True,
                 max_image_size: int = 3200, max_num_features: int = 8192, num_threads: int = 2,
                 use_gpu: bool = False, camera_params: Sequence[float] | None = None, first_octave: int = -1) -> None:
    """Import the images and extract SIFT features into the database. `single_camera`: one shared set of
    intrinsics for all images (one physical camera, fixed zoom); `camera_params` optionally seeds them."""
    if camera_model not in CAMERA_MODELS:
        raise ValueError(f"camera model {camera_model!r} not supported; use one of {', '.join(CAMERA_MODELS)}")
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    if camera_params is not None:
        reader.camera_params = ",".join(f"{v:.10g}" for v in camera_params)
    mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.AUTO
    names = list(image_names) if image_names else []
    if hasattr(pycolmap, "FeatureExtractionOptions"):  # 3.12+/4.x
        ext = pycolmap.FeatureExtractionOptions()
        ext.max_image_size = int(max_image_size)
        ext.num_threads = int(num_threads)
        _set_first(ext, ["use_gpu"], bool(use_gpu))
        ext.sift.max_num_features = int(max_num_features)
        _set_first(ext.sift, ["first_octave"], int(first_octave))
        _call(pycolmap.extract_features, str(database_path), str(image_dir), image_names=names, camera_mode=mode,
              reader_options=reader, extraction_options=ext, device=_device(use_gpu))
    else:  # 3.10/3.11
        sift = pycolmap.SiftExtractionOptions()
        sift.max_image_size = int(max_image_size)
        sift.max_num_features = int(max_num_features)
        _set_first(sift, ["first_octave"], int(first_octave))
        sift.num_threads = int(num_threads)
        _call(pycolmap.extract_features, str(database_path), str(image_dir), image_list=names, camera_mode=mode,
              reader_options=reader, sift_options=sift, device=_device(use_gpu))


# ----------------------------------------------------------------------------- matching

def _matching_options(num_threads: int, max_num_matches: int, guided: bool, random_seed: int | None = 0):
    """Matching options; `random_seed` seeds the RANSAC of the geometric verification (COLMAP's default,
    -1, draws a new seed per pair and run: the verified matches, and so the model, changed run to run)."""
    if hasattr(pycolmap, "FeatureMatchingOptions"):
        m = pycolmap.FeatureMatchingOptions()
        m.num_threads = int(num_threads)
        m.max_num_matches = int(max_num_matches)
        m.guided_matching = bool(guided)
        kw = {"matching_options": m}
        if random_seed is not None and hasattr(pycolmap, "TwoViewGeometryOptions"):
            v = pycolmap.TwoViewGeometryOptions()
            ransac = getattr(v, "ransac", None)
            if ransac is not None and _set_first(ransac, ["random_seed"], int(random_seed)):
                v.ransac = ransac
                kw["verification_options"] = v
        return kw
    m = pycolmap.SiftMatchingOptions()
    m.num_threads = int(num_threads)
    m.max_num_matches = int(max_num_matches)
    m.guided_matching = bool(guided)
    return {"sift_options": m}


def _pairing(cls_names: Sequence[str], legacy_kw: str, **values):
    for name in cls_names:
        cls = getattr(pycolmap, name, None)
        if cls is not None:
            opts = cls()
            for k, v in values.items():
                _set_first(opts, [k], v)
            kw = "pairing_options" if name.endswith("PairingOptions") else legacy_kw
            return {kw: opts}
    return {}


def match_exhaustive(database_path, num_threads: int = 2, max_num_matches: int = 32768, guided: bool = False,
                     use_gpu: bool = False, random_seed: int | None = 0) -> None:
    kw = _matching_options(num_threads, max_num_matches, guided, random_seed)
    kw.update(_pairing(["ExhaustivePairingOptions", "ExhaustiveMatchingOptions"], "matching_options"))
    _call(pycolmap.match_exhaustive, str(database_path), device=_device(use_gpu), **kw)


def match_sequential(database_path, overlap: int = 10, quadratic_overlap: bool = True, num_threads: int = 2,
                     max_num_matches: int = 32768, guided: bool = False, use_gpu: bool = False,
                     random_seed: int | None = 0) -> None:
    """Match each image with the next `overlap` ones in name order (and 2^k-th ones if quadratic)."""
    kw = _matching_options(num_threads, max_num_matches, guided, random_seed)
    kw.update(_pairing(["SequentialPairingOptions", "SequentialMatchingOptions"], "matching_options",
                       overlap=int(overlap), quadratic_overlap=bool(quadratic_overlap), loop_detection=False))
    _call(pycolmap.match_sequential, str(database_path), device=_device(use_gpu), **kw)


def match_spatial(database_path, positions: dict[str, Sequence[float]], max_num_neighbors: int = 20,
                  max_distance_m: float = 100.0, ignore_z: bool = True, num_threads: int = 2,
                  max_num_matches: int = 32768, guided: bool = False, use_gpu: bool = False,
                  random_seed: int | None = 0) -> None:
    """Match each image with its `max_num_neighbors` nearest ones (within `max_distance_m`) by the given
    metric positions (image name -> x, y, z in a local frame), written as Cartesian pose priors."""
    write_position_priors(database_path, positions)
    kw = _matching_options(num_threads, max_num_matches, guided, random_seed)
    kw.update(_pairing(["SpatialPairingOptions", "SpatialMatchingOptions"], "matching_options",
                       max_num_neighbors=int(max_num_neighbors), max_distance=float(max_distance_m),
                       ignore_z=bool(ignore_z), is_gps=False))
    _call(pycolmap.match_spatial, str(database_path), device=_device(use_gpu), **kw)


# ----------------------------------------------------------------------------- mapping

def incremental_mapping(database_path, image_dir, output_dir, num_threads: int = 2,
                        refine_focal_length: bool = True, refine_principal_point: bool = False,
                        refine_extra_params: bool = True, multiple_models: bool = True, min_model_size: int = 3,
                        random_seed: int = 0, next_image_callback: Callable[[], None] | None = None,
                        global_ba_growth: float | None = None, global_ba_max_iterations: int | None = None,
                        local_ba_max_iterations: int | None = None) -> MappingOutput:
    """Run COLMAP's incremental mapper. Models are written to output_dir/0, 1, ...; returns them largest
    first with the largest converted to plain data."""
    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    opts = pycolmap.IncrementalPipelineOptions() if hasattr(pycolmap, "IncrementalPipelineOptions") \
        else pycolmap.IncrementalMapperOptions()
    _set_first(opts, ["num_threads"], int(num_threads))
    _set_first(opts, ["ba_refine_focal_length"], bool(refine_focal_length))
    _set_first(opts, ["ba_refine_principal_point"], bool(refine_principal_point))
    _set_first(opts, ["ba_refine_extra_params"], bool(refine_extra_params))
    _set_first(opts, ["multiple_models"], bool(multiple_models))
    _set_first(opts, ["min_model_size"], int(min_model_size))
    if random_seed is not None:
        _set_first(opts, ["random_seed"], int(random_seed))
        mapper = getattr(opts, "mapper", None)
        if mapper is not None and _set_first(mapper, ["random_seed"], int(random_seed)):
            opts.mapper = mapper
        if hasattr(pycolmap, "set_random_seed"):
            pycolmap.set_random_seed(int(random_seed))
    if global_ba_growth is not None:
        _set_first(opts, ["ba_global_frames_ratio", "ba_global_images_ratio"], float(global_ba_growth))
        _set_first(opts, ["ba_global_points_ratio"], float(global_ba_growth))
    if global_ba_max_iterations is not None:
        _set_first(opts, ["ba_global_max_num_iterations"], int(global_ba_max_iterations))
    if local_ba_max_iterations is not None:
        _set_first(opts, ["ba_local_max_num_iterations"], int(local_ba_max_iterations))
    kwargs = {"options": opts}
    if next_image_callback is not None:
        kwargs["next_image_callback"] = next_image_callback
    try:
        models = pycolmap.incremental_mapping(str(database_path), str(image_dir), str(output_dir), **kwargs)
    except TypeError:
        kwargs.pop("next_image_callback", None)
        models = pycolmap.incremental_mapping(str(database_path), str(image_dir), str(output_dir), **kwargs)
    ordered = sorted(models.values(), key=lambda r: r.num_reg_images(), reverse=True)
    best = reconstruction_data(ordered[0]) if ordered else None
    return MappingOutput(models=ordered, best=best, model_sizes=[int(r.num_reg_images()) for r in ordered])


def write_model(model, out_dir) -> Path:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    model.write(str(out_dir))
    return out_dir


def read_model(model_dir) -> ReconstructionData:
    rec = pycolmap.Reconstruction(str(model_dir))
    return reconstruction_data(rec)


# ----------------------------------------------------------------------------- conversion

def reconstruction_data(rec) -> ReconstructionData:
    """Convert a pycolmap.Reconstruction into plain dataclasses and arrays."""
    cameras = {}
    for cid, cam in rec.cameras.items():
        model = cam.model_name if hasattr(cam, "model_name") else str(cam.model).split(".")[-1]
        info = cam.params_info
        names = [s.strip() for s in (info() if callable(info) else info).split(",")]
        cameras[int(cid)] = CameraData(camera_id=int(cid), model=str(model), width=int(cam.width),
                                       height=int(cam.height), params=[float(v) for v in cam.params],
                                       param_names=names)
    images = {}
    for iid, im in rec.images.items():
        has_pose = im.has_pose if hasattr(im, "has_pose") else getattr(im, "registered", True)
        if callable(has_pose):
            has_pose = has_pose()
        if not has_pose:
            continue
        pose = _cam_from_world(im)
        R = _matrix(pose.rotation)
        t = np.asarray(pose.translation, dtype=float).reshape(3)
        n3 = im.num_points3D
        images[int(iid)] = ImageData(image_id=int(iid), name=im.name, camera_id=int(im.camera_id),
                                     R_cam_from_world=R, t_cam_from_world=t, centre=-R.T @ t,
                                     num_points3D=int(n3() if callable(n3) else n3))
    n = len(rec.points3D)
    xyz = np.zeros((n, 3))
    rgb = np.zeros((n, 3), dtype=np.uint8)
    err = np.zeros(n)
    tl = np.zeros(n, dtype=int)
    obs_img: list[int] = []
    obs_pt: list[int] = []
    obs_p2d: list[int] = []
    for k, p in enumerate(rec.points3D.values()):
        xyz[k] = p.xyz
        rgb[k] = p.color
        err[k] = p.error
        tl[k] = p.track.length()
        for el in p.track.elements:
            obs_img.append(int(el.image_id))
            obs_pt.append(k)
            obs_p2d.append(int(el.point2D_idx))
    obs_xy = np.zeros((len(obs_img), 2))
    if obs_img:
        by_image: dict[int, list[int]] = {}
        for row, iid in enumerate(obs_img):
            by_image.setdefault(iid, []).append(row)
        for iid, rows in by_image.items():
            pts2d = rec.images[iid].points2D
            for row in rows:
                obs_xy[row] = pts2d[obs_p2d[row]].xy
    mre = float(rec.compute_mean_reprojection_error()) if n else float("nan")
    return ReconstructionData(cameras=cameras, images=images, points_xyz=xyz, points_rgb=rgb, points_error_px=err,
                              points_track_length=tl, mean_reprojection_error_px=mre,
                              mean_track_length=float(tl.mean()) if n else 0.0,
                              obs_image_id=np.asarray(obs_img, dtype=int), obs_point_index=np.asarray(obs_pt, dtype=int),
                              obs_xy_px=obs_xy)



def set_log_level(verbose: bool) -> None:
    """COLMAP's glog output: everything (verbose) or warnings and errors only."""
    log = getattr(pycolmap, "logging", None)
    if log is None:
        return
    with contextlib.suppress(AttributeError, TypeError):
        log.minloglevel = 0 if verbose else 1
