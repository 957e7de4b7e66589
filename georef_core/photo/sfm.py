"""Step: structure from motion. Feature extraction, matching (matcher chosen from the image count and
the known positions) and incremental mapping of a folder of images; writes the COLMAP model and a JSON
summary into a work folder. The CLI and the worker call this same function."""

from __future__ import annotations

import json
import shutil
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ProcessingError
from . import colmap_api
from .images import MIN_PHOTOS_PER_CAMERA, ImageInfo, group_cameras, local_positions_m, read_images

from ..progress import ProgressFn  # (stage, done, total)

MATCHERS = ("auto", "exhaustive", "spatial", "sequential")


@dataclass
class SfmOptions:
    camera_model: str = "SIMPLE_RADIAL"  # SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV, ...
    single_camera: bool = True  # one set of intrinsics per camera group (make/model, size, focal length)
    # a camera group (images.group_cameras) with fewer photos is left out, each photo named in a warning
    min_photos_per_camera: int = MIN_PHOTOS_PER_CAMERA
    matcher: str = "auto"
    exhaustive_max_images: int = 30  # auto: exhaustive up to this many images
    spatial_max_neighbors: int = 20
    spatial_max_distance_m: float = 150.0
    sequential_overlap: int = 10
    max_image_size: int = 3200
    max_num_features: int = 4096
    # SIFT's first octave: -1 (COLMAP's default) doubles the image first and finds the smallest features;
    # 0 starts at full resolution: 5x faster extraction on 1600-px images, same registration (measured).
    # None: 0 when the images' long side is at least 1200 px, else -1 (small images need the fine scales)
    sift_first_octave: int | None = None
    # incremental mapper: a global bundle adjustment each time the model grew by this factor, and the
    # iteration caps of global / local adjustments (COLMAP: 1.1, unlimited, unlimited); the GNSS-aided
    # adjustment after SfM re-refines everything, so SfM's own refinement can be lighter (measured: same
    # registration and reprojection error on 102 images, mapping 194 s -> 100 s)
    mapper_global_ba_growth: float = 2.0
    mapper_global_ba_max_iterations: int = 20
    mapper_local_ba_max_iterations: int = 10
    num_threads: int = 2  # 1: single-threaded (reproducible timings); -1: all cores
    use_gpu: bool = False
    refine_principal_point: bool = False
    random_seed: int = 0  # RANSAC of matching and mapping: same photos and options, same model
    verbose: bool = False  # COLMAP's own log (glog) on stderr
    positions: dict[str, tuple[float, float, float]] | None = None  # name -> local metric xyz (else EXIF GPS)


def _first_octave(opts: SfmOptions, infos) -> int:
    if opts.sift_first_octave is not None:
        return int(opts.sift_first_octave)
    long_side = min((max(i.width, i.height) for i in infos), default=0)
    return 0 if long_side >= 1200 else -1


@dataclass
class SfmResult:
    work_dir: Path
    model_dir: Path | None
    summary_path: Path
    matcher: str
    n_images: int
    n_registered: int
    mean_reprojection_error_px: float
    timings_s: dict
    reconstruction: colmap_api.ReconstructionData | None
    images: list[ImageInfo] = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    left_out: list[dict] = field(default_factory=list)   # photos not used: image, camera, reason

    def centres_by_name(self) -> dict[str, np.ndarray]:
        if self.reconstruction is None:
            return {}
        return {im.name: im.centre for im in self.reconstruction.images.values()}


def choose_matcher(n_images: int, have_positions: bool, options: SfmOptions) -> str:
    if options.matcher != "auto":
        if options.matcher not in MATCHERS:
            raise ValueError(f"matcher {options.matcher!r}: use one of {', '.join(MATCHERS)}")
        if options.matcher == "spatial" and not have_positions:
            raise ProcessingError("spatial matching needs image positions (EXIF GPS or options.positions)")
        return options.matcher
    if n_images <= options.exhaustive_max_images:
        return "exhaustive"
    return "spatial" if have_positions else "sequential"


IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".png")


def sfm_inputs_key(image_dir, options: SfmOptions) -> str:
    """A hash of what an SfM result depends on: every image's name, size and first and last 64 KiB (the
    EXIF block and enough pixels to tell an edited or replaced photo), the options and the pycolmap
    version. A stored model is reused only under the same key: adding, removing or replacing a photo,
    or changing an option, runs SfM again.

    The given camera positions only choose which pairs are matched, and only with the spatial matcher:
    they enter the key (to the centimetre) when the matcher resolves to "spatial", and not otherwise
    (an exhaustive or sequential block's result does not depend on them, so a re-run with other GNSS
    positions - a new PPK, RTK tags instead of raw PPK - reuses the model)."""
    import hashlib

    h = hashlib.sha256()
    n_images = 0
    for p in sorted(Path(image_dir).iterdir()):
        if p.suffix.lower() not in IMAGE_SUFFIXES or not p.is_file():
            continue
        n_images += 1
        size = p.stat().st_size
        h.update(f"{p.name}\0{size}\0".encode())
        with open(p, "rb") as fh:
            h.update(fh.read(65536))
            if size > 131072:
                fh.seek(-65536, 2)
                h.update(fh.read(65536))
    opts = {k: v for k, v in asdict(options).items() if k != "positions"}
    try:    # the folder's count bounds the kept images' count: "exhaustive" here is exhaustive in run_sfm
        spatial = choose_matcher(n_images, bool(options.positions), options) == "spatial"
    except (ValueError, ProcessingError):
        spatial = True
    pos = {n: [round(float(c), 2) for c in v] for n, v in sorted((options.positions or {}).items())} if spatial else {}
    h.update(json.dumps({"options": opts, "positions": pos, "pycolmap": colmap_api.PYCOLMAP_VERSION},
                        sort_keys=True, default=str).encode())
    return h.hexdigest()


def run_sfm(image_dir, work_dir, options: SfmOptions | None = None, progress: ProgressFn | None = None) -> SfmResult:
    """Run SfM on the images of `image_dir`; everything is (re)written under `work_dir`:
    `database.db`, `sparse/0` (the largest model, COLMAP binary), `sfm_summary.json`."""
    opts = options or SfmOptions()
    image_dir, work_dir = Path(image_dir), Path(work_dir)
    report = progress or (lambda stage, done, total: None)
    colmap_api.set_log_level(opts.verbose)
    t_start = time.perf_counter()
    timings: dict[str, float] = {}

    report("reading images", 0, 1)
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        infos = read_images(image_dir)
    exif_warnings = [str(w.message) for w in caught]
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    timings["read_images"] = time.perf_counter() - t0
    if len(infos) < 2:
        raise InputFileError(image_dir, f"SfM needs at least 2 images, found {len(infos)}")
    # one camera per (make/model, size, focal length); groups too small to calibrate are left out, named
    groups, left_out = group_cameras(infos, opts.min_photos_per_camera)
    for lo in left_out:
        warnings.warn(lo["reason"], UserWarning, stacklevel=2)
    all_infos = infos
    kept_names = {n for g in groups for n in g.names}
    infos = [i for i in infos if i.name in kept_names]

    positions, frame = (opts.positions, {"type": "given"}) if opts.positions else local_positions_m(infos)
    matcher = choose_matcher(len(infos), positions is not None, opts)

    work_dir.mkdir(parents=True, exist_ok=True)
    db_path = work_dir / "database.db"
    sparse = work_dir / "sparse"
    raw = work_dir / "mapper_models"
    for p in (sparse, raw):
        if p.exists():
            shutil.rmtree(p)
    colmap_api.open_database(db_path, fresh=True).close()
    names = [i.name for i in infos]

    report("extraction", 0, len(infos))
    t0 = time.perf_counter()
    for g in groups:   # one extraction per group: COLMAP makes one camera for each (largest group: camera 1)
        colmap_api.extract_sift(db_path, image_dir, image_names=g.names, camera_model=opts.camera_model,
                                single_camera=opts.single_camera, max_image_size=opts.max_image_size,
                                max_num_features=opts.max_num_features, num_threads=opts.num_threads,
                                use_gpu=opts.use_gpu, first_octave=_first_octave(opts, infos))
    colmap_api.number_images_by_name(db_path)   # ids in name order, not in the threads' finishing order
    timings["extraction"] = time.perf_counter() - t0
    report("extraction", len(infos), len(infos))

    report("matching", 0, 1)
    t0 = time.perf_counter()
    common = {"num_threads": opts.num_threads, "use_gpu": opts.use_gpu, "random_seed": opts.random_seed}
    if matcher == "exhaustive":
        colmap_api.match_exhaustive(db_path, **common)
    elif matcher == "spatial":
        colmap_api.match_spatial(db_path, positions, max_num_neighbors=opts.spatial_max_neighbors,
                                 max_distance_m=opts.spatial_max_distance_m, **common)
    else:
        colmap_api.match_sequential(db_path, overlap=opts.sequential_overlap, **common)
    timings["matching"] = time.perf_counter() - t0
    counts = colmap_api.database_counts(db_path)
    report("matching", 1, 1)

    registered = [0]

    def on_next_image():
        registered[0] += 1
        report("mapping", min(registered[0] + 1, len(infos)), len(infos))

    report("mapping", 0, len(infos))
    t0 = time.perf_counter()
    out = colmap_api.incremental_mapping(db_path, image_dir, raw, num_threads=opts.num_threads,
                                         refine_principal_point=opts.refine_principal_point,
                                         random_seed=opts.random_seed, next_image_callback=on_next_image,
                                         global_ba_growth=opts.mapper_global_ba_growth,
                                         global_ba_max_iterations=opts.mapper_global_ba_max_iterations,
                                         local_ba_max_iterations=opts.mapper_local_ba_max_iterations)
    timings["mapping"] = time.perf_counter() - t0
    rec = out.best
    model_dir = None
    if out.models:
        model_dir = colmap_api.write_model(out.models[0], sparse / "0")
    shutil.rmtree(raw, ignore_errors=True)
    report("mapping", rec.num_registered if rec else 0, len(infos))
    timings["total"] = time.perf_counter() - t_start

    n = len(infos)
    summary = {
        "image_dir": str(image_dir),
        "pycolmap_version": colmap_api.PYCOLMAP_VERSION,
        "n_images": n,
        "n_images_in_folder": len(all_infos),
        "camera_groups": [g.to_dict() for g in groups],
        "left_out": left_out,
        "matcher": matcher,
        "positions_frame": frame if positions is not None else None,
        "options": {k: v for k, v in asdict(opts).items() if k != "positions"},
        "inputs_key": sfm_inputs_key(image_dir, opts),
        "database": counts,
        "models": out.model_sizes,
        "n_registered": rec.num_registered if rec else 0,
        "unregistered": sorted(set(names) - {im.name for im in rec.images.values()}) if rec else names,
        "n_points3D": len(rec.points_xyz) if rec else 0,
        "mean_reprojection_error_px": round(rec.mean_reprojection_error_px, 4) if rec else None,
        "mean_track_length": round(rec.mean_track_length, 3) if rec else None,
        "cameras": [asdict(c) for c in rec.cameras.values()] if rec else [],
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
        "time_per_image_s": {k: round(timings[k] / n, 4) for k in ("extraction", "matching", "mapping")},
        "model_dir": str(model_dir) if model_dir else None,
        "exif_warnings": exif_warnings,
    }
    summary_path = work_dir / "sfm_summary.json"
    summary_path.write_text(json.dumps(summary, indent=2))
    report("done", 1, 1)
    return SfmResult(work_dir=work_dir, model_dir=model_dir, summary_path=summary_path, matcher=matcher,
                     n_images=n, n_registered=summary["n_registered"],
                     mean_reprojection_error_px=rec.mean_reprojection_error_px if rec else float("nan"),
                     timings_s=timings, reconstruction=rec, images=infos, summary=summary, left_out=left_out)
