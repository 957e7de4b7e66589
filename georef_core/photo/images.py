"""Image inputs of the photogrammetry steps: listing a folder and reading each image's EXIF (time,
focal length, sensor size, camera make/model, GPS) into plain dataclasses."""

from __future__ import annotations

import datetime as dt
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")

# FocalPlaneResolutionUnit: 2 inch, 3 cm, 4 mm, 5 um (1 = none, treated as inch per the EXIF spec default)
_UNIT_MM = {1: 25.4, 2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}
_FULL_FRAME_DIAGONAL_MM = float(np.hypot(36.0, 24.0))


class ExifWarning(UserWarning):
    """An image lacks an EXIF field the processing would use."""


@dataclass
class ImageInfo:
    path: Path
    name: str
    width: int
    height: int
    make: str | None = None
    model: str | None = None
    time_original: dt.datetime | None = None  # DateTimeOriginal + SubSecTimeOriginal (+ offset if given)
    focal_length_mm: float | None = None
    focal_length_35mm: float | None = None
    sensor_width_mm: float | None = None
    sensor_height_mm: float | None = None
    gps_lat_deg: float | None = None
    gps_lon_deg: float | None = None
    gps_alt_m: float | None = None
    missing: list[str] = field(default_factory=list)  # names of the EXIF fields not found

    @property
    def has_gps(self) -> bool:
        return self.gps_lat_deg is not None and self.gps_lon_deg is not None

    @property
    def focal_length_px(self) -> float | None:
        """Focal length in pixels from the focal length and sensor width, else from the 35 mm equivalent."""
        if self.focal_length_mm and self.sensor_width_mm:
            return self.focal_length_mm / self.sensor_width_mm * self.width
        if self.focal_length_35mm:
            return self.focal_length_35mm / _FULL_FRAME_DIAGONAL_MM * float(np.hypot(self.width, self.height))
        return None


def list_images(image_dir) -> list[Path]:
    """The image files of a folder (sorted by name). Raises InputFileError naming the folder when it is
    missing, not a folder or holds no image."""
    d = Path(image_dir)
    if not d.exists():
        raise InputFileError(d, "image folder does not exist")
    if not d.is_dir():
        raise InputFileError(d, "is not a folder of images")
    files = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
                   and not p.name.startswith("."))
    if not files:
        raise InputFileError(d, f"no image files ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return files


def _num(v) -> float | None:
    if v is None:
        return None
    if isinstance(v, tuple) and len(v) == 2 and all(isinstance(x, int) for x in v):
        return float(v[0]) / v[1] if v[1] else None
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


def _text(v) -> str | None:
    if v is None:
        return None
    if isinstance(v, bytes):
        v = v.decode("ascii", errors="replace")
    v = str(v).strip("\x00 ").strip()
    return v or None


def _dms(v, ref) -> float | None:
    try:
        d, m, s = (_num(x) for x in v)
    except (TypeError, ValueError):
        return None
    if d is None or m is None or s is None:
        return None
    val = d + m / 60.0 + s / 3600.0
    ref = _text(ref) or ""
    return -val if ref.upper() in ("S", "W") else val


def _parse_time(dto, subsec, offset) -> dt.datetime | None:
    s = _text(dto)
    if not s:
        return None
    try:
        t = dt.datetime.strptime(s, "%Y:%m:%d %H:%M:%S")
    except ValueError:
        return None
    sub = _text(subsec)
    if sub and sub.isdigit():
        t = t + dt.timedelta(seconds=float("0." + sub))
    off = _text(offset)
    if off and len(off) >= 6 and off[0] in "+-":
        try:
            hh, mm = int(off[1:3]), int(off[4:6])
            sign = 1 if off[0] == "+" else -1
            t = t.replace(tzinfo=dt.timezone(sign * dt.timedelta(hours=hh, minutes=mm)))
        except ValueError:
            pass
    return t


def read_image_info(path, warn: bool = True) -> ImageInfo:
    """Read the size and EXIF of one image. InputFileError (naming the file) when it is missing or not a
    readable image; an ExifWarning lists the fields it lacks."""
    import piexif
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "image file does not exist")
    try:
        with Image.open(path) as im:
            width, height = im.size
            im.verify()
            raw_exif = im.info.get("exif")
    except (UnidentifiedImageError, OSError, SyntaxError) as e:
        raise InputFileError(path, f"not a readable image ({e.__class__.__name__}: {e})") from None
    info = ImageInfo(path=path, name=path.name, width=int(width), height=int(height))
    exif = {"0th": {}, "Exif": {}, "GPS": {}}
    if raw_exif:
        try:
            from .exif_bounds import exif_problem

            problem = exif_problem(raw_exif)      # piexif trusts every tag's value count (gigabytes, seconds)
            if problem:
                raise ValueError(problem)
            exif = piexif.load(raw_exif)
        except Exception as e:  # noqa: BLE001  (piexif raises anything on a corrupt EXIF block): the pixels are still usable
            if warn:
                warnings.warn(f"{path}: EXIF block unreadable ({e}); processing without it", ExifWarning, stacklevel=2)
    z, x, g = exif.get("0th", {}), exif.get("Exif", {}), exif.get("GPS", {})
    T = piexif.ImageIFD, piexif.ExifIFD, piexif.GPSIFD
    info.make = _text(z.get(T[0].Make))
    info.model = _text(z.get(T[0].Model))
    info.time_original = _parse_time(x.get(T[1].DateTimeOriginal), x.get(T[1].SubSecTimeOriginal),
                                     x.get(T[1].OffsetTimeOriginal))
    info.focal_length_mm = _num(x.get(T[1].FocalLength)) or None
    info.focal_length_35mm = _num(x.get(T[1].FocalLengthIn35mmFilm)) or None
    xres, yres = _num(x.get(T[1].FocalPlaneXResolution)), _num(x.get(T[1].FocalPlaneYResolution))
    unit_mm = _UNIT_MM.get(int(x.get(T[1].FocalPlaneResolutionUnit, 2)), 25.4)
    if xres:
        info.sensor_width_mm = width / xres * unit_mm
        info.sensor_height_mm = height / (yres or xres) * unit_mm
    elif info.focal_length_mm and info.focal_length_35mm:
        # crop factor from the 35 mm equivalent (diagonal convention)
        diag = _FULL_FRAME_DIAGONAL_MM * info.focal_length_mm / info.focal_length_35mm
        k = diag / float(np.hypot(width, height))
        info.sensor_width_mm, info.sensor_height_mm = width * k, height * k
    if T[2].GPSLatitude in g and T[2].GPSLongitude in g:
        info.gps_lat_deg = _dms(g[T[2].GPSLatitude], g.get(T[2].GPSLatitudeRef))
        info.gps_lon_deg = _dms(g[T[2].GPSLongitude], g.get(T[2].GPSLongitudeRef))
        alt = _num(g.get(T[2].GPSAltitude))
        if alt is not None:
            info.gps_alt_m = -alt if g.get(T[2].GPSAltitudeRef, 0) == 1 else alt
    for name, val in (("DateTimeOriginal", info.time_original), ("FocalLength", info.focal_length_mm),
                      ("sensor size (FocalPlaneResolution or FocalLengthIn35mmFilm)", info.sensor_width_mm),
                      ("Make/Model", info.model), ("GPS position", info.gps_lat_deg)):
        if val is None:
            info.missing.append(name)
    if warn and info.missing:
        warnings.warn(f"{path}: EXIF lacks {', '.join(info.missing)}", ExifWarning, stacklevel=2)
    return info


def read_images(image_dir, warn: bool = True) -> list[ImageInfo]:
    """Read every image of a folder. Missing-field warnings are grouped (one per field over the folder)."""
    files = list_images(image_dir)
    infos = [read_image_info(p, warn=False) for p in files]
    if warn:
        fields: dict[str, list[str]] = {}
        for i in infos:
            for m in i.missing:
                fields.setdefault(m, []).append(i.name)
        for m, names in fields.items():
            some = ", ".join(names[:3]) + (" ..." if len(names) > 3 else "")
            warnings.warn(f"{Path(image_dir)}: EXIF {m} missing in {len(names)}/{len(infos)} images ({some})",
                          ExifWarning, stacklevel=2)
    return infos


def local_positions_m(infos: list[ImageInfo]) -> tuple[dict[str, np.ndarray], dict] | tuple[None, None]:
    """EXIF GPS positions converted to a local metric frame (ENU metres at the mean position, via ECEF).
    Returns (name -> xyz, frame description) or (None, None) when fewer than 3 images carry GPS."""
    from ..gnss.frames import ecef_delta_to_enu_m, geodetic_to_ecef_m

    with_gps = [i for i in infos if i.has_gps]
    if len(with_gps) < 3:
        return None, None
    lat = np.radians([i.gps_lat_deg for i in with_gps])
    lon = np.radians([i.gps_lon_deg for i in with_gps])
    alt = np.array([i.gps_alt_m if i.gps_alt_m is not None else 0.0 for i in with_gps])
    ecef = np.array([geodetic_to_ecef_m(a, b, h) for a, b, h in zip(lat, lon, alt)]).reshape(-1, 3)
    lat0, lon0, h0 = float(np.mean(lat)), float(np.mean(lon)), float(np.mean(alt))
    origin = np.asarray(geodetic_to_ecef_m(lat0, lon0, h0), dtype=float).reshape(3)
    enu = np.asarray(ecef_delta_to_enu_m(ecef - origin, origin), dtype=float).reshape(-1, 3)
    frame = {"type": "ENU", "origin_lat_deg": float(np.degrees(lat0)), "origin_lon_deg": float(np.degrees(lon0)),
             "origin_h_m": h0}
    return {i.name: enu[k] for k, i in enumerate(with_gps)}, frame


# ----------------------------------------------------------------------------- camera groups

# A camera group is calibrated from its own photos (one set of intrinsics for the group). With fewer than
# this many photos its eight intrinsics rest on the one or two photos' own tie points, where the focal
# length trades with the photo's height and the distortion with its tilt (a resection with a free camera):
# such photos are left out, named, rather than allowed to bend the block or the DSM where they are the
# only view (docs/georeferencing.md, "Mixed image sets").
MIN_PHOTOS_PER_CAMERA = 3


@dataclass
class CameraGroup:
    """Photos taken with one camera at one setting: same EXIF make and model, same image size in pixels,
    same EXIF focal length (a zoom or a second drone makes another group; so does a resized or cropped
    copy)."""

    make: str | None
    model: str | None
    width: int
    height: int
    focal_length_mm: float | None
    names: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        cam = " ".join(v for v in (self.make, self.model) if v) or "unknown camera"
        focal = f"{self.focal_length_mm:g} mm" if self.focal_length_mm else "no EXIF focal length"
        return f"{cam}, {self.width} x {self.height} px, {focal}"

    def to_dict(self) -> dict:
        return {"make": self.make, "model": self.model, "width": self.width, "height": self.height,
                "focal_length_mm": self.focal_length_mm, "label": self.label, "n_images": len(self.names),
                "images": list(self.names)}


def camera_key(info: ImageInfo) -> tuple:
    """What tells one camera (setting) from another: make, model, size, focal length (to 0.01 mm)."""
    focal = round(float(info.focal_length_mm), 2) if info.focal_length_mm else None
    return ((info.make or "").strip().lower(), (info.model or "").strip().lower(), int(info.width),
            int(info.height), focal)


def group_cameras(infos: list[ImageInfo], min_photos: int = MIN_PHOTOS_PER_CAMERA
                  ) -> tuple[list[CameraGroup], list[dict]]:
    """Group the photos by camera (``camera_key``): (groups with at least ``min_photos`` photos, largest
    first; left-out photos as dicts with ``image``, ``camera`` and ``reason``). When no group reaches
    ``min_photos`` every photo is kept in its group (there is nothing better to calibrate with)."""
    by_key: dict[tuple, CameraGroup] = {}
    for i in infos:
        k = camera_key(i)
        if k not in by_key:
            by_key[k] = CameraGroup(i.make, i.model, int(i.width), int(i.height), k[4])
        by_key[k].names.append(i.name)
    groups = sorted(by_key.values(), key=lambda g: (-len(g.names), g.names[0]))
    if not any(len(g.names) >= min_photos for g in groups):
        return groups, []
    kept = [g for g in groups if len(g.names) >= min_photos]
    left_out = []
    main = kept[0]
    for g in groups:
        if len(g.names) >= min_photos:
            continue
        differs = []
        if (g.width, g.height) != (main.width, main.height):
            differs.append(f"{g.width} x {g.height} px where the main camera's photos are {main.width} x {main.height}")
        if (g.make, g.model) != (main.make, main.model):
            differs.append(f"camera {' '.join(v for v in (g.make, g.model) if v) or 'unknown'}")
        if g.focal_length_mm != main.focal_length_mm:
            differs.append(f"focal length {g.focal_length_mm if g.focal_length_mm else 'unknown'} mm")
        for name in g.names:
            left_out.append({"image": name, "camera": g.label,
                             "reason": (f"{name}: left out: {'; '.join(differs) or 'another camera'}, and only "
                                        f"{len(g.names)} photo{'s' if len(g.names) > 1 else ''} of that camera "
                                        f"(at least {min_photos} are needed to calibrate a camera; a resized, "
                                        f"cropped or stray photo?)")})
    return kept, left_out
