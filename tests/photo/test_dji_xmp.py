"""drone-dji XMP tags: the real Phantom 4 RTK dump of ../shared/data/dji (skipped when absent) and
synthetic JPEGs with the XMP packet in attribute and element form."""

from __future__ import annotations

import datetime as dt
import io
import os
import struct
from pathlib import Path

import pytest

from georef_core.errors import InputFileError
from georef_core.photo.dji_xmp import MAX_XMP_SEARCH_BYTES, parse_dji_xmp_text, read_dji_xmp

XMP_APP1_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
DEWARP = "2018-03-13;3659.78,3653.17,-7.71,45.90,-0.269478,0.115681,-0.0000875619,-0.000306177,-0.0357628"

ATTRIBUTE_FORM = f"""<x:xmpmeta xmlns:x="adobe:ns:meta/">
 <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
  <rdf:Description rdf:about="DJI Meta Data"
    xmlns:tiff="http://ns.adobe.com/tiff/1.0/"
    xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"
   tiff:Make="DJI" tiff:Model="FC6310R"
   drone-dji:AbsoluteAltitude="+116.56" drone-dji:RelativeAltitude="+69.95"
   drone-dji:GpsLatitude="43.36511377" drone-dji:GpsLongtitude="141.81345593"
   drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalYawDegree="-79.00" drone-dji:GimbalPitchDegree="-89.90"
   drone-dji:FlightRollDegree="-2.50" drone-dji:FlightYawDegree="-78.60" drone-dji:FlightPitchDegree="-4.50"
   drone-dji:FlightXSpeed="+0.50" drone-dji:FlightYSpeed="-2.90" drone-dji:FlightZSpeed="+0.00"
   drone-dji:CalibratedFocalLength="3666.666504"
   drone-dji:CalibratedOpticalCenterX="2432.000000" drone-dji:CalibratedOpticalCenterY="1824.000000"
   drone-dji:RtkFlag="50" drone-dji:RtkStdLon="0.01274" drone-dji:RtkStdLat="0.01122" drone-dji:RtkStdHgt="0.02394"
   drone-dji:DewarpData="{DEWARP}" drone-dji:DewarpFlag="0" drone-dji:SelfData="Undefined"/>
 </rdf:RDF>
</x:xmpmeta>"""

ELEMENT_FORM = f"""<x:xmpmeta xmlns:x="adobe:ns:meta/">
 <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
  <rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"
    xmlns:tiff="http://ns.adobe.com/tiff/1.0/">
   <tiff:Make>DJI</tiff:Make>
   <tiff:Model>M3E</tiff:Model>
   <drone-dji:RtkFlag>16</drone-dji:RtkFlag>
   <drone-dji:RtkStdLat> 1.2 </drone-dji:RtkStdLat>
   <drone-dji:GpsLatitude>-36.41144502</drone-dji:GpsLatitude>
   <drone-dji:GpsLongitude>174.63075195</drone-dji:GpsLongitude>
   <drone-dji:GimbalPitchDegree>-90.0</drone-dji:GimbalPitchDegree>
   <drone-dji:DewarpData>{DEWARP}</drone-dji:DewarpData>
  </rdf:Description>
 </rdf:RDF>
</x:xmpmeta>"""


def _dji_dump() -> Path:
    env = os.environ.get("GEOREF_SHARED_DATA")
    root = Path(env) if env else Path(__file__).resolve().parents[2].parent / "shared"
    for cand in (root / "data" / "dji", root / "dji"):
        if (cand / "p4rtk_auckland_2018" / "dji_rtk.exif").is_file():
            return cand / "p4rtk_auckland_2018" / "dji_rtk.exif"
    pytest.skip("shared DJI data not available (set GEOREF_SHARED_DATA)")


def _jpeg(tmp_path, name: str, xmp: str | None = None, pad_before: int = 0) -> Path:
    """A small real JPEG (PIL) with an APP1 XMP segment spliced in after SOI (and optional padding APP2
    segments before it)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (32, 24), (120, 90, 60)).save(buf, format="JPEG")
    data = buf.getvalue()
    assert data[:2] == b"\xff\xd8"
    segments = b""
    while pad_before > 0:
        n = min(pad_before, 65000)
        segments += b"\xff\xe2" + struct.pack(">H", n + 2) + b"\x00" * n
        pad_before -= n
    if xmp is not None:
        payload = XMP_APP1_HEADER + b'<?xpacket begin="\xef\xbb\xbf" id="W5M0MpCehiHzreSzNTczkc9d"?>' \
            + xmp.encode() + b'<?xpacket end="w"?>'
        segments += b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    p = tmp_path / name
    p.write_bytes(data[:2] + segments + data[2:])
    return p


def test_real_dump():
    x = read_dji_xmp(_dji_dump())
    assert x is not None and x.rtk_flag == 50 and x.rtk_fixed
    assert x.rtk_std_lat_m == pytest.approx(0.01122) and x.rtk_std_lon_m == pytest.approx(0.01274)
    assert x.rtk_std_hgt_m == pytest.approx(0.02394)
    assert x.gps_latitude_deg == pytest.approx(43.36511377) and x.gps_longitude_deg == pytest.approx(141.81345593)
    assert x.absolute_altitude_m == pytest.approx(116.56) and x.relative_altitude_m == pytest.approx(69.95)
    assert x.gimbal_pitch_deg == pytest.approx(-89.9) and x.flight_yaw_deg == pytest.approx(-78.6)
    assert x.flight_speed_y_m_s == pytest.approx(-2.9) and x.flight_speed_z_m_s == 0.0
    assert x.calibrated_focal_length_px == pytest.approx(3666.666504)
    assert x.calibrated_optical_center_x_px == 2432.0 and x.calibrated_optical_center_y_px == 1824.0
    d = x.dewarp
    assert d is not None and d.calibration_date == dt.date(2018, 3, 13)
    assert d.fx_px == pytest.approx(3659.78) and d.fy_px == pytest.approx(3653.17)
    assert (d.cx_offset_px, d.cy_offset_px) == pytest.approx((-7.71, 45.9)) and d.k3 == pytest.approx(-0.0357628)
    assert d.principal_point_px(4864, 3648) == pytest.approx((2432 - 7.71, 1824 + 45.9))
    assert x.dewarp_flag == 0 and (x.make, x.model) == ("DJI", "FC6310R")
    assert x.raw["SelfData"] == "Undefined" and x.raw["GpsLongtitude"] == "141.81345593" and len(x.raw) == 25


def test_jpeg_attribute_form(tmp_path):
    x = read_dji_xmp(_jpeg(tmp_path, "DJI_0001.JPG", ATTRIBUTE_FORM))
    assert x is not None and x.rtk_fixed and x.rtk_std_lat_m == pytest.approx(0.01122)
    assert x.gps_longitude_deg == pytest.approx(141.81345593) and x.gimbal_yaw_deg == pytest.approx(-79.0)
    assert x.dewarp.fx_px == pytest.approx(3659.78) and (x.make, x.model) == ("DJI", "FC6310R")
    assert x.raw["RtkFlag"] == "50" and "Make" not in x.raw
    # same result from the packet text
    y = parse_dji_xmp_text(ATTRIBUTE_FORM, "packet.xmp")
    assert y.raw == x.raw and y.dewarp == x.dewarp


def test_jpeg_element_form(tmp_path):
    x = read_dji_xmp(_jpeg(tmp_path, "DJI_0002.JPG", ELEMENT_FORM))
    assert x is not None and x.rtk_flag == 16 and not x.rtk_fixed
    assert x.rtk_std_lat_m == pytest.approx(1.2) and x.rtk_std_lon_m is None
    assert x.gps_longitude_deg == pytest.approx(174.63075195)   # the GpsLongitude spelling
    assert x.gimbal_pitch_deg == -90.0 and x.model == "M3E" and x.dewarp.cy_offset_px == pytest.approx(45.9)


def test_xmp_after_large_segments_within_window(tmp_path):
    x = read_dji_xmp(_jpeg(tmp_path, "pad.JPG", ATTRIBUTE_FORM, pad_before=150_000))
    assert x is not None and x.rtk_fixed
    # beyond the window: not seen
    assert read_dji_xmp(_jpeg(tmp_path, "far.JPG", ATTRIBUTE_FORM, pad_before=MAX_XMP_SEARCH_BYTES)) is None


def test_jpeg_without_dji_tags_returns_none(tmp_path):
    assert read_dji_xmp(_jpeg(tmp_path, "plain.jpg")) is None
    other = '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">' \
            '<rdf:Description xmlns:tiff="http://ns.adobe.com/tiff/1.0/" tiff:Make="Canon"/></rdf:RDF></x:xmpmeta>'
    assert read_dji_xmp(_jpeg(tmp_path, "canon.jpg", other)) is None


def test_entity_declaration_refused(tmp_path):
    evil = ATTRIBUTE_FORM.replace('<x:xmpmeta xmlns:x="adobe:ns:meta/">',
                                  '<x:xmpmeta xmlns:x="adobe:ns:meta/"><!DOCTYPE x [<!ENTITY a "aaaaaaaaaa">]>')
    p = _jpeg(tmp_path, "evil.jpg", evil)
    with pytest.raises(InputFileError) as e:
        read_dji_xmp(p)
    assert str(p) in str(e.value) and "ENTITY" in e.value.problem


def test_bad_number_names_file_and_tag(tmp_path):
    p = _jpeg(tmp_path, "bad.jpg", ATTRIBUTE_FORM.replace('RtkStdLat="0.01122"', 'RtkStdLat="0.0l122"'))
    with pytest.raises(InputFileError) as e:
        read_dji_xmp(p)
    assert str(p) in str(e.value) and "RtkStdLat" in e.value.problem
    with pytest.raises(InputFileError, match="DewarpData"):
        parse_dji_xmp_text(ATTRIBUTE_FORM.replace("-7.71,", ""), "short_dewarp.xmp")
    with pytest.raises(InputFileError) as e:
        parse_dji_xmp_text('drone-dji: RtkFlag = "fifty"\n', "dump.txt")
    assert e.value.line == 1 and "RtkFlag" in e.value.problem


def test_broken_packets(tmp_path):
    with pytest.raises(InputFileError, match="not well-formed"):
        read_dji_xmp(_jpeg(tmp_path, "broken.jpg", ATTRIBUTE_FORM.replace("</rdf:RDF>", "")))
    p = tmp_path / "cut.jpg"
    p.write_bytes(_jpeg(tmp_path, "whole.jpg", ATTRIBUTE_FORM).read_bytes()[:400])
    with pytest.raises(InputFileError, match="not closed"):
        read_dji_xmp(p)
    with pytest.raises(InputFileError, match="not found"):
        read_dji_xmp(tmp_path / "missing.jpg")


def test_exiv2_dump_lines():
    x = parse_dji_xmp_text("Xmp.drone-dji.RtkFlag                        XmpText     2  50\n"
                           "Xmp.drone-dji.GimbalPitchDegree              XmpText     6  -90.00\n"
                           "Xmp.tiff.Model                               XmpText     7  FC6310R\n", "exiv2.txt")
    assert x.rtk_fixed and x.gimbal_pitch_deg == -90.0 and x.model == "FC6310R"
    assert parse_dji_xmp_text("tiff:Make = \"DJI\"\n", "no_dji.txt") is None
