"""What a survey folder holds, recognised by content: the standard layout (``images/``, ``rover/``,
``base/``, ``nav/``, ``events.csv``, ``gcp/``) or DJI flight folders as the aircraft writes them.

A DJI flight folder is any folder of the survey that holds a ``Timestamp.MRK`` (found by content, not
name) beside its photos (or, for a single flight, an MRK in any folder with the photos in ``images/``)
and, for PPK, the aircraft's raw GNSS log (``*_PPKRAW.bin`` RTCM 3, M4's
``.rtk``, a UBX log or the aircraft's ``*_Rinex.obs``) and possibly its navigation file. A survey may
hold several such folders (battery swaps): they are joined in time order, with the gaps between
flights reported. The base station's files stay in ``base/`` (one or several: hourly CORS files, a
log split by restarts), navigation files in ``nav/``, control/check points in ``gcp/``.

For the DJI layout ``survey_inputs`` writes into ``OUT_DIR/inputs/``:
* ``images/``: links to every flight's photos (names prefixed by their flight folder where two
  flights use the same photo name), so the later steps see one image folder;
* ``events.csv``: image, gps_time_s (the MRK exposure times: the triggers);
* ``camera_offsets.csv``: image, antenna -> camera offset north/east/down (m) of that exposure, the
  MRK's own quality flag and flight.

Photos are tied to MRK exposures by the number at the end of their name (``DJI_0042.JPG`` is exposure
42; ``DJI_20241126120000_0042_V.JPG`` too), else in name order when the counts agree. A flight whose
photos and exposures disagree in count, or whose photo EXIF times do not follow the MRK times (the
spread of EXIF time minus MRK time over the flight, after removing the time zone, exceeds 3 s),
is refused with a message naming both files.
"""

from __future__ import annotations

import csv
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".png")
_JPEG_TIFF_MAGIC = (b"\xff\xd8\xff", b"II*\x00", b"MM\x00*")
STANDARD_FOLDERS = ("images", "rover", "base", "nav", "gcp")
_PHOTO_NUMBER = re.compile(r"(\d+)(?:_[A-Za-z]{1,3})?\.(?:jpe?g|tiff?|png)$", re.IGNORECASE)
MAX_EXIF_MRK_SPREAD_S = 3.0
_SKIP_DIRS = {"base", "gcp", "nav", "__MACOSX"}


@dataclass
class DjiFlight:
    """One flight folder of a DJI aircraft."""

    folder: Path
    mrk_path: Path
    photos: list[Path]                      # in the folder, sorted by name
    raw_logs: list[Path]                    # the aircraft's GNSS observations (RTCM 3, UBX, RINEX obs)
    nav_files: list[Path]                   # RINEX navigation files written beside them
    image_names: list[str] = field(default_factory=list)   # names in OUT_DIR/inputs/images
    exposure_of_photo: list[int] = field(default_factory=list)   # row of the MRK of each photo


@dataclass
class SurveyInputs:
    """Where each input of a survey is (see module docstring)."""

    survey_dir: Path
    layout: str                             # "standard" or "dji"
    image_dir: Path
    image_names: list[str]
    rover_files: list[Path]
    base_files: list[Path]
    nav_files: list[Path]
    events_csv: Path | None
    camera_offsets_csv: Path | None = None
    flights: list[DjiFlight] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    rtk_cross_check: dict | None = None     # the MRK's RTK quality against the photos' XMP (rtk_cross_check.py)

    def summary(self) -> dict:
        """What was found, as the pre-flight and the step summaries state it."""
        out = {"layout": self.layout, "images": len(self.image_names),
               "rover_files": [p.name for p in self.rover_files], "base_files": [p.name for p in self.base_files],
               "nav_files": [p.name for p in self.nav_files]}
        if self.flights:
            out["flights"] = [{"folder": f.folder.name, "photos": len(f.photos), "mrk": f.mrk_path.name,
                               "raw_logs": [p.name for p in f.raw_logs]} for f in self.flights]
        if self.rtk_cross_check is not None:
            out["rtk_cross_check"] = self.rtk_cross_check
        return out


def _file_kind(path: Path) -> str:
    """'image', a GNSS kind of input_files.sniff_kind, or 'unknown'."""
    from ..gnss.input_files import sniff_kind

    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError:
        return "unknown"
    if head[:3] == _JPEG_TIFF_MAGIC[0] or head in _JPEG_TIFF_MAGIC[1:] or head == b"\x89PNG":
        return "image"
    try:
        return sniff_kind(path)
    except InputFileError:
        return "unknown"


def _visible_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))


def find_dji_flights(survey_dir: Path, max_depth: int = 3) -> list[DjiFlight]:
    """Every folder under the survey (base/, gcp/ and nav/ excluded) that holds a DJI Timestamp.MRK."""
    flights: list[DjiFlight] = []
    survey_dir = Path(survey_dir)

    def visit(folder: Path, depth: int) -> None:
        files = _visible_files(folder)
        kinds = {}
        for p in files:
            if p.suffix.lower() in IMAGE_SUFFIXES:
                kinds[p] = "image"
            else:
                kinds[p] = _file_kind(p)
        mrks = [p for p in files if kinds[p] == "dji-mrk"]
        if len(mrks) > 1:
            raise InputFileError(folder, f"{len(mrks)} Timestamp.MRK files in one flight folder "
                                         f"({', '.join(p.name for p in mrks)}): keep each flight in its own folder")
        if mrks:
            flights.append(DjiFlight(
                folder=folder, mrk_path=mrks[0], photos=[p for p in files if kinds[p] == "image"],
                raw_logs=[p for p in files if kinds[p] in ("rtcm3", "ubx", "rinex-obs")],
                nav_files=[p for p in files if kinds[p] == "rinex-nav"]))
        if depth < max_depth:
            for sub in sorted(d for d in folder.iterdir() if d.is_dir() and not d.name.startswith(".")):
                if depth == 0 and sub.name in _SKIP_DIRS:
                    continue
                visit(sub, depth + 1)

    visit(survey_dir, 0)
    # an MRK uploaded apart from its photos (e.g. into rover/) with the photos in images/: one flight
    bare = [f for f in flights if not f.photos]
    images = survey_dir / "images"
    if len(bare) == 1 and len(flights) == 1 and images.is_dir():
        bare[0].photos = [p for p in _visible_files(images) if p.suffix.lower() in IMAGE_SUFFIXES]
    return flights


def _photo_numbers(photos: list[Path]) -> list[int] | None:
    nums = []
    for p in photos:
        m = _PHOTO_NUMBER.search(p.name)
        if m is None:
            return None
        nums.append(int(m.group(1)))
    return nums if len(set(nums)) == len(nums) else None


def read_photo_infos(photos: list[Path]) -> dict[Path, object]:
    """EXIF of each photo (photo.images.ImageInfo), read once for every check; unreadable photos are left
    out (the SfM step names them)."""
    from ..photo.images import read_image_info

    infos = {}
    for p in photos:
        try:
            infos[p] = read_image_info(p, warn=False)
        except InputFileError:
            continue
    return infos


def match_photos_to_exposures(flight: DjiFlight, mrk, infos: dict | None = None) -> tuple[list[int], list[str]]:
    """Row of the MRK of each photo of a flight, and warnings. Raises InputFileError naming the MRK and
    the photo folder when they cannot belong together."""
    warnings: list[str] = []
    n_photo, n_exp = len(flight.photos), mrk.n_exposures
    if n_photo == 0:
        raise InputFileError(flight.folder, f"{flight.mrk_path.name} lists {n_exp} exposures but the folder has no "
                                            "photos")
    nums = _photo_numbers(flight.photos)
    row_of_index = {int(k): i for i, k in enumerate(mrk.index.tolist())}
    if nums is not None and all(k in row_of_index for k in nums):
        rows = [row_of_index[k] for k in nums]
        how = "photo numbers"
    elif n_photo == n_exp:
        rows = list(range(n_photo))
        how = "order"
    else:
        unknown = [p.name for p, k in zip(flight.photos, nums or []) if k not in row_of_index][:5]
        detail = f" (no exposure for {', '.join(unknown)})" if unknown else ""
        raise InputFileError(flight.mrk_path, f"{n_exp} exposures but {n_photo} photos in {flight.folder}{detail}: "
                                              "the MRK does not belong to these photos")
    if n_exp > n_photo:
        warnings.append(f"{flight.mrk_path.name}: {n_exp - n_photo} exposure(s) without a photo in {flight.folder.name} "
                        "(deleted photos?)")
    infos = infos if infos is not None else read_photo_infos(flight.photos)
    spread = _exif_time_spread_s(flight.photos, mrk.gps_time_s[np.asarray(rows)], infos)
    if spread is not None and spread > MAX_EXIF_MRK_SPREAD_S:
        raise InputFileError(flight.mrk_path, f"the photos' EXIF times do not follow the MRK times (matched by {how}): "
                                              f"their difference varies by {spread:.1f} s over {flight.folder} (more "
                                              f"than {MAX_EXIF_MRK_SPREAD_S:g} s): the MRK does not belong to these "
                                              "photos, or photos were renamed")
    return rows, warnings


def _exif_time_spread_s(photos: list[Path], mrk_gps_s: np.ndarray, infos: dict) -> float | None:
    """Spread (max - min) of EXIF time minus MRK time over a flight; the differences (time zone, GPS-UTC
    leap seconds, the camera clock's error) are constant for one flight, and are folded into one quarter
    hour of the first one so a zone does not count; None when fewer than two photos have an EXIF time."""
    from ..gnss.gnss_time import gps_time_s_to_datetime

    diffs = []
    for p, t_gps in zip(photos, mrk_gps_s.tolist()):
        t = infos[p].time_original if p in infos else None
        if t is None:
            continue
        d = (t.replace(tzinfo=None) - gps_time_s_to_datetime(t_gps)).total_seconds()
        diffs.append(d)
    if len(diffs) < 2:
        return None
    d = np.asarray(diffs)
    d = d - 900.0 * np.round((d - d[0]) / 900.0)         # one zone for all
    # EXIF seconds are whole (no sub-seconds on many cameras): up to 1 s of truncation
    return float(d.max() - d.min())


def _link(src: Path, dst: Path) -> None:
    if dst.is_symlink() or dst.exists():
        if dst.is_symlink() and Path(os.readlink(dst)) == src.resolve():
            return
        dst.unlink()
    try:
        dst.symlink_to(src.resolve())
    except OSError:
        shutil.copy2(src, dst)


def survey_inputs(survey_dir, out_dir) -> SurveyInputs:
    """Find the survey's inputs (module docstring); for DJI flight folders write OUT_DIR/inputs/."""
    from ..gnss.dji_mrk import join_mrk, read_mrk

    survey_dir, out = Path(survey_dir), Path(out_dir)
    base_files = _gnss_files(survey_dir / "base", ("rinex-obs", "ubx", "rtcm3"))
    nav_files = _gnss_files(survey_dir / "nav", ("rinex-nav", "rtcm3", "ubx"))
    flights = find_dji_flights(survey_dir)
    if not flights:
        image_dir = survey_dir / "images"
        names = sorted(p.name for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES) \
            if image_dir.is_dir() else []
        return SurveyInputs(survey_dir, "standard", image_dir, names,
                            _gnss_files(survey_dir / "rover", ("rinex-obs", "ubx", "rtcm3")), base_files, nav_files,
                            survey_dir / "events.csv" if (survey_dir / "events.csv").is_file() else None)
    warnings: list[str] = []
    mrks = [read_mrk(f.mrk_path) for f in flights]
    order = np.argsort([m.gps_time_s[0] if m.n_exposures else np.inf for m in mrks], kind="stable")
    flights = [flights[k] for k in order]
    mrks = [mrks[k] for k in order]
    joined = join_mrk(mrks)
    warnings += joined.warnings
    for g in joined.flight_gaps:
        warnings.append(f"{g.duration_s:.0f} s between flights {flights[g.before_flight].folder.name} and "
                        f"{flights[g.after_flight].folder.name}")
    infos = read_photo_infos([p for f in flights for p in f.photos])
    _check_one_aircraft(flights, infos, warnings)
    inputs_dir = out / "inputs"
    image_dir = inputs_dir / "images"
    image_dir.mkdir(parents=True, exist_ok=True)
    all_names = [p.name for f in flights for p in f.photos]
    clash = len(set(all_names)) < len(all_names)
    rows_out, pairs = [], []
    for fi, (flight, mrk) in enumerate(zip(flights, mrks)):
        rows, w = match_photos_to_exposures(flight, mrk, infos)
        warnings += w
        flight.exposure_of_photo = rows
        for photo, r in zip(flight.photos, rows):
            name = f"{flight.folder.name}_{photo.name}" if clash else photo.name
            _link(photo, image_dir / name)
            flight.image_names.append(name)
            rows_out.append((name, float(mrk.gps_time_s[r]), *[float(v) for v in mrk.camera_offset_ned_m[r]],
                             int(mrk.quality[r]), fi))
            pairs.append((name, photo, int(mrk.quality[r]), mrk.sigma_ned_m[r]))
    keep = {r[0] for r in rows_out}
    for stale in image_dir.iterdir():          # a photo removed since an earlier run
        if stale.name not in keep:
            stale.unlink()
    rows_out.sort(key=lambda r: r[1])
    events_csv = inputs_dir / "events.csv"
    with open(events_csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["image", "gps_time_s"])
        for r in rows_out:
            w.writerow([r[0], f"{r[1]:.6f}"])
    offsets_csv = inputs_dir / "camera_offsets.csv"
    write_camera_offsets(offsets_csv, rows_out)
    rover_files = [p for f in flights for p in f.raw_logs] or \
        _gnss_files(survey_dir / "rover", ("rinex-obs", "ubx", "rtcm3"))
    nav_files = nav_files + [p for f in flights for p in f.nav_files]
    from ..photo.rtk_cross_check import cross_check_mrk_xmp, cross_check_warning

    cross = cross_check_mrk_xmp(pairs)
    w = cross_check_warning(cross, "the camera positions come from the PPK of the raw log, so neither record enters "
                            "the adjustment" if rover_files else "the adjustment uses the photos' XMP positions, "
                            "sigmas and RtkFlag (no raw log)")
    warnings += [w] if w else []
    warnings += [f"unreadable XMP: {u}" for u in cross["unreadable_xmp"][:5]]
    return SurveyInputs(survey_dir, "dji", image_dir, sorted(keep), rover_files, base_files, nav_files, events_csv,
                        offsets_csv, flights, warnings, rtk_cross_check=cross)


def write_camera_offsets(path: Path, rows) -> None:
    """rows: (image, trigger_gps_time_s, north_m, east_m, down_m, mrk_quality, flight)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["image", "trigger_gps_time_s", "north_m", "east_m", "down_m", "mrk_quality", "flight"])
        for r in rows:
            w.writerow([r[0], f"{r[1]:.6f}", f"{r[2]:.4f}", f"{r[3]:.4f}", f"{r[4]:.4f}", r[5], r[6]])


def read_camera_offsets(path: Path) -> dict[str, np.ndarray]:
    """image -> antenna-to-camera offset (north, east, down, m) of its exposure."""
    with open(path) as f:
        return {r["image"]: np.array([float(r["north_m"]), float(r["east_m"]), float(r["down_m"])])
                for r in csv.DictReader(f)}


def read_camera_flights(path: Path) -> dict[str, int | None]:
    """image -> the flight (flight folder, in the order written) of its exposure; None where the table gives none."""
    with open(path) as f:
        return {r["image"]: int(r["flight"]) if r.get("flight") not in (None, "") else None for r in csv.DictReader(f)}


def _check_one_aircraft(flights: list[DjiFlight], infos: dict, warnings: list[str]) -> None:
    """Photos of one flight from two cameras are refused; flights of different aircraft are named."""
    models_by_flight = []
    for fl in flights:
        models: dict[str, list[str]] = {}
        for p in fl.photos:
            info = infos.get(p)
            if info is None:
                continue
            models.setdefault(f"{info.make or '?'} {info.model or '?'} {info.width}x{info.height}", []).append(p.name)
        if len(models) > 1:
            parts = "; ".join(f"{m}: {len(n)} ({', '.join(n[:2])}{' ...' if len(n) > 2 else ''})"
                              for m, n in models.items())
            raise InputFileError(fl.folder, f"photos from more than one camera in one flight folder ({parts}): one "
                                            "aircraft's flight per folder")
        models_by_flight.append(next(iter(models), "?"))
    if len(set(models_by_flight)) > 1:
        named = ", ".join(f"{fl.folder.name}: {m}" for fl, m in zip(flights, models_by_flight))
        warnings.append(f"the flights were made with different cameras ({named}): each is calibrated on its own")


def _gnss_files(folder: Path, kinds: tuple[str, ...]) -> list[Path]:
    if not folder.is_dir():
        return []
    return [p for p in _visible_files(folder)
            if p.suffix.lower() not in (".md", ".txt", ".json", ".csv") and _file_kind(p) in kinds]
