"""The ``drone-dji:`` XMP tags of a DJI photo: RTK status and accuracy, aircraft and gimbal attitude,
speed, and the factory / user camera calibration.

A DJI JPEG carries an XMP packet (an APP1 segment ``http://ns.adobe.com/xap/1.0/\\0`` + XML) in which
the tags are attributes of ``rdf:Description`` (``drone-dji:RtkFlag="50"``) or, in some firmware,
child elements (``<drone-dji:RtkFlag>50</drone-dji:RtkFlag>``). ``read_dji_xmp`` looks for
``<x:xmpmeta ... </x:xmpmeta>`` in the first 256 KiB of the file (any container: JPEG, TIFF, DNG) and
parses it with ``xml.etree``; packets that declare a DOCTYPE or an ENTITY are refused (entity expansion
attacks; a real XMP packet has neither). Text dumps are read too: ``drone-dji: Key = "value"`` lines (as in
an XMP toolkit dump) and ``Xmp.drone-dji.Key  XmpText  N  value`` lines (``exiv2 -px``).

Units and conventions (DJI's manuals; all values are as written by the aircraft):

* ``RtkFlag``: 0 no position, 16 single point, 34 (32-49) RTK float, 50 RTK fixed (the MRK ``Q`` codes).
* ``RtkStdLon/Lat/Hgt``: standard deviations (m) of the real-time position east / north / up.
* ``GpsLatitude``, ``GpsLongtitude`` (DJI's spelling; ``GpsLongitude`` on newer models): degrees, the
  camera position per DJI.
* ``AbsoluteAltitude``: m; its datum depends on the model and firmware (EGM96 geoid on most aircraft,
  ellipsoidal on some RTK firmware): check before use. ``RelativeAltitude``: m above the take-off point.
* ``Gimbal*Degree``, ``Flight*Degree``: degrees, attitude of the gimbal / aircraft in the local NED frame,
  rotation order Z-Y-X (yaw from true north, clockwise; gimbal pitch -90 = camera looking straight down).
* ``FlightX/Y/ZSpeed``: m/s, north / east / vertical. DJI's SDK uses north-east-down (z positive down);
  the manuals only say "elevation direction", so treat the sign of z with care.
* ``CalibratedFocalLength``, ``CalibratedOpticalCenterX/Y``: pixels, the lens design values (the optical
  centre from the top-left image corner; it is width/2, height/2 on a Phantom 4 RTK).
* ``DewarpData``: ``"YYYY-MM-DD;fx,fy,cx,cy,k1,k2,p1,p2,k3"``: the per-unit calibration, fx, fy in pixels,
  **cx, cy the principal point's offset from the image centre in pixels** (principal point =
  (width/2 + cx, height/2 + cy)), k1 k2 k3 radial and p1 p2 tangential (Brown-Conrady, OpenCV order).
  ``DewarpFlag``: 1 when the image was already undistorted in the aircraft, 0 when not.
"""

from __future__ import annotations

import datetime as dt
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputFileError

__all__ = ["DjiXmp", "DjiDewarp", "read_dji_xmp", "parse_dji_xmp_text", "find_xmp_packets", "MAX_XMP_SEARCH_BYTES"]

MAX_XMP_SEARCH_BYTES = 256 * 1024
DJI_NAMESPACE = "http://www.dji.com/drone-dji/1.0/"
TIFF_NAMESPACE = "http://ns.adobe.com/tiff/1.0/"
RTK_FIXED = 50

_XMP_START = b"<x:xmpmeta"
_XMP_END = b"</x:xmpmeta>"
_UNSAFE = re.compile(rb"<!\s*(?:DOCTYPE|ENTITY)", re.IGNORECASE)

# drone-dji tag -> DjiXmp field (floats)
_FLOAT_TAGS = {
    "RtkStdLon": "rtk_std_lon_m",
    "RtkStdLat": "rtk_std_lat_m",
    "RtkStdHgt": "rtk_std_hgt_m",
    "GpsLatitude": "gps_latitude_deg",
    "GpsLongtitude": "gps_longitude_deg",
    "GpsLongitude": "gps_longitude_deg",
    "AbsoluteAltitude": "absolute_altitude_m",
    "RelativeAltitude": "relative_altitude_m",
    "GimbalRollDegree": "gimbal_roll_deg",
    "GimbalPitchDegree": "gimbal_pitch_deg",
    "GimbalYawDegree": "gimbal_yaw_deg",
    "FlightRollDegree": "flight_roll_deg",
    "FlightPitchDegree": "flight_pitch_deg",
    "FlightYawDegree": "flight_yaw_deg",
    "FlightXSpeed": "flight_speed_x_m_s",
    "FlightYSpeed": "flight_speed_y_m_s",
    "FlightZSpeed": "flight_speed_z_m_s",
    "CalibratedFocalLength": "calibrated_focal_length_px",
    "CalibratedOpticalCenterX": "calibrated_optical_center_x_px",
    "CalibratedOpticalCenterY": "calibrated_optical_center_y_px",
}
_INT_TAGS = {"RtkFlag": "rtk_flag", "DewarpFlag": "dewarp_flag"}
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_DUMP_LINE = re.compile(r'^\s*(drone-dji|tiff):\s*(\w+)\s*=\s*"(.*)"\s*$')
_EXIV2_LINE = re.compile(r"^\s*Xmp\.(drone-dji|tiff)\.(\w+)\s+\w+\s+\d+\s*(.*?)\s*$")


@dataclass
class DjiDewarp:
    """``drone-dji:DewarpData``: a calibration of the camera (Brown-Conrady, OpenCV coefficient order)."""

    calibration_date: dt.date | None
    fx_px: float
    fy_px: float
    cx_offset_px: float     # principal point x minus width / 2 (pixels)
    cy_offset_px: float     # principal point y minus height / 2 (pixels)
    k1: float
    k2: float
    p1: float
    p2: float
    k3: float

    def principal_point_px(self, width_px: int, height_px: int) -> tuple[float, float]:
        """Principal point (x, y) in pixels from the top-left image corner."""
        return width_px / 2.0 + self.cx_offset_px, height_px / 2.0 + self.cy_offset_px


@dataclass
class DjiXmp:
    """The drone-dji tags of one photo (None: tag absent or empty). See the module doc for conventions."""

    source_path: str
    rtk_flag: int | None = None
    rtk_std_lon_m: float | None = None
    rtk_std_lat_m: float | None = None
    rtk_std_hgt_m: float | None = None
    gps_latitude_deg: float | None = None
    gps_longitude_deg: float | None = None
    absolute_altitude_m: float | None = None
    relative_altitude_m: float | None = None
    gimbal_roll_deg: float | None = None
    gimbal_pitch_deg: float | None = None
    gimbal_yaw_deg: float | None = None
    flight_roll_deg: float | None = None
    flight_pitch_deg: float | None = None
    flight_yaw_deg: float | None = None
    flight_speed_x_m_s: float | None = None      # north
    flight_speed_y_m_s: float | None = None      # east
    flight_speed_z_m_s: float | None = None      # vertical (down in DJI's SDK convention)
    calibrated_focal_length_px: float | None = None
    calibrated_optical_center_x_px: float | None = None
    calibrated_optical_center_y_px: float | None = None
    dewarp: DjiDewarp | None = None
    dewarp_flag: int | None = None
    make: str | None = None      # tiff:Make
    model: str | None = None     # tiff:Model
    raw: dict[str, str] = field(default_factory=dict)   # every drone-dji tag, as text

    @property
    def rtk_fixed(self) -> bool:
        return self.rtk_flag == RTK_FIXED


# ============================================================================ public API
def read_dji_xmp(path) -> DjiXmp | None:
    """The drone-dji tags of a photo (or of a text dump of them); None when there are none.

    Only the first ``MAX_XMP_SEARCH_BYTES`` of the file are read. Raises InputFileError for a missing
    file, an XMP packet that is not closed in that window, malformed or unsafe XML, or a bad number."""
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "file not found")
    if p.is_dir():
        raise InputFileError(p, "is a folder, expected a photo")
    try:
        with open(p, "rb") as fh:
            data = fh.read(MAX_XMP_SEARCH_BYTES)
    except OSError as exc:
        raise InputFileError(p, f"cannot be read ({exc.strerror or exc})") from None
    packets = find_xmp_packets(data, str(p))
    if packets:
        return _from_tags(_merge(_packet_tags(pk, str(p)) for pk in packets), str(p))
    if b"\x00" not in data[:4096] and (b"drone-dji:" in data or b"Xmp.drone-dji." in data):
        return parse_dji_xmp_text(data.decode("utf-8", errors="replace"), str(p))
    return None


def parse_dji_xmp_text(text: str, source_path: str = "<text>") -> DjiXmp | None:
    """The drone-dji tags of an XMP packet (XML text) or of a text dump (``drone-dji: Key = "value"`` or
    ``exiv2 -px`` lines); None when there are none."""
    if _XMP_START.decode() in text:
        packets = find_xmp_packets(text.encode("utf-8"), source_path)
        return _from_tags(_merge(_packet_tags(pk, source_path) for pk in packets), source_path)
    tags: dict[tuple[str, str], tuple[str, int | None]] = {}
    for k, line in enumerate(text.split("\n")):
        m = _DUMP_LINE.match(line) or _EXIV2_LINE.match(line)
        if m:
            tags.setdefault((m.group(1), m.group(2)), (m.group(3).strip(), k + 1))
    return _from_tags(tags, source_path)


def find_xmp_packets(data: bytes, source_path: str = "<bytes>") -> list[bytes]:
    """Every ``<x:xmpmeta ...>...</x:xmpmeta>`` in ``data`` (a photo's first bytes), in file order.
    Raises InputFileError when a packet is not closed (cut off, or longer than the bytes given)."""
    packets = []
    start = data.find(_XMP_START)
    while start >= 0:
        end = data.find(_XMP_END, start)
        if end < 0:
            raise InputFileError(source_path, f"the XMP packet starting at byte {start} is not closed within the "
                                 f"first {len(data)} bytes (file cut off?)")
        end += len(_XMP_END)
        packets.append(data[start:end])
        start = data.find(_XMP_START, end)
    return packets


# ============================================================================ internals
def _packet_tags(packet: bytes, source_path: str) -> dict[tuple[str, str], tuple[str, int | None]]:
    """{(prefix, name): (text, line)} of the drone-dji and tiff tags of one XMP packet."""
    if _UNSAFE.search(packet):
        raise InputFileError(source_path, "the XMP packet declares a DOCTYPE or ENTITY; refused (XML entity "
                             "expansion is not allowed in photo metadata)")
    try:
        root = ET.fromstring(packet)
    except ET.ParseError as exc:
        raise InputFileError(source_path, f"the XMP packet is not well-formed XML ({exc})") from None
    declared = re.findall(rb"""xmlns:drone-dji\s*=\s*["']([^"']*)["']""", packet)
    dji_uris = {DJI_NAMESPACE} | {u.decode("utf-8", "replace") for u in declared}
    prefixes = {**{u: "drone-dji" for u in dji_uris}, TIFF_NAMESPACE: "tiff"}
    tags: dict[tuple[str, str], tuple[str, int | None]] = {}

    def add(qname: str, value: str) -> None:
        if qname.startswith("{"):
            uri, _, name = qname[1:].partition("}")
            if uri in prefixes:
                tags.setdefault((prefixes[uri], name), (value.strip(), None))

    for elem in root.iter():
        for name, value in elem.attrib.items():
            add(name, value)
        if isinstance(elem.tag, str) and len(elem) == 0:
            add(elem.tag, elem.text or "")
    return tags


def _merge(tag_dicts) -> dict:
    merged: dict = {}
    for d in tag_dicts:
        for k, v in d.items():
            merged.setdefault(k, v)
    return merged


def _from_tags(tags: dict[tuple[str, str], tuple[str, int | None]], source_path: str) -> DjiXmp | None:
    raw = {name: value for (prefix, name), (value, _) in tags.items() if prefix == "drone-dji"}
    if not raw:
        return None
    lines = {name: line for (prefix, name), (_, line) in tags.items() if prefix == "drone-dji"}
    out = DjiXmp(source_path=source_path, raw=raw)
    for name, value in raw.items():
        if name in _FLOAT_TAGS:
            attr = _FLOAT_TAGS[name]
            if getattr(out, attr) is None:
                setattr(out, attr, _float(value, name, source_path, lines[name]))
        elif name in _INT_TAGS:
            setattr(out, _INT_TAGS[name], _int(value, name, source_path, lines[name]))
    if "DewarpData" in raw:
        out.dewarp = _dewarp(raw["DewarpData"], source_path, lines["DewarpData"])
    for attr, name in (("make", "Make"), ("model", "Model")):
        if ("tiff", name) in tags:
            setattr(out, attr, tags[("tiff", name)][0].strip() or None)
    return out


def _float(value: str, tag: str, source_path: str, line: int | None) -> float | None:
    v = value.strip()
    if not v:
        return None
    if not _NUMBER.fullmatch(v):
        raise InputFileError(source_path, f"XMP tag drone-dji:{tag} = {value!r} is not a number", line=line)
    x = float(v)
    if not math.isfinite(x):
        raise InputFileError(source_path, f"XMP tag drone-dji:{tag} = {value!r} is not finite", line=line)
    return x


def _int(value: str, tag: str, source_path: str, line: int | None) -> int | None:
    v = value.strip()
    if not v:
        return None
    if not re.fullmatch(r"[-+]?\d+", v):
        raise InputFileError(source_path, f"XMP tag drone-dji:{tag} = {value!r} is not an integer", line=line)
    return int(v)


def _dewarp(value: str, source_path: str, line: int | None) -> DjiDewarp | None:
    v = value.strip()
    if not v:
        return None
    date_text, _, numbers = v.rpartition(";")
    parts = [p.strip() for p in numbers.split(",")]
    if len(parts) != 9:
        raise InputFileError(source_path, f"XMP tag drone-dji:DewarpData has {len(parts)} numbers, expected 9 "
                             "(fx,fy,cx,cy,k1,k2,p1,p2,k3)", line=line)
    vals = [_float(p, "DewarpData", source_path, line) for p in parts]
    if any(x is None for x in vals):
        raise InputFileError(source_path, f"XMP tag drone-dji:DewarpData {value!r} has an empty number", line=line)
    date = None
    if date_text.strip():
        try:
            date = dt.date.fromisoformat(date_text.strip())
        except ValueError:
            raise InputFileError(source_path, f"XMP tag drone-dji:DewarpData date {date_text.strip()!r} is not "
                                 "YYYY-MM-DD", line=line) from None
    return DjiDewarp(date, *vals)

