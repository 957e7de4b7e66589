"""The GNSS receiver and antenna models: read from real RINEX headers (tests/data/rinex, REC # / TYPE / VERS and
ANT # / TYPE), from an RTCM 3 stream's 1033 message and a u-blox log's MON-VER, named by the format where a log
states none (u-blox UBX, a DJI aircraft's RTCM 3 log), and printed in the survey report's GNSS section (read
back with pdftotext)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from georef_core.gnss.input_files import load_observations
from georef_core.gnss.receiver_equipment import equipment_of_loaded, equipment_text, receiver_equipment

RINEX = Path(__file__).resolve().parents[1] / "data" / "rinex"


def _eq(name: str) -> dict:
    p = RINEX / name
    return equipment_of_loaded(load_observations(p), p)


def test_receiver_and_antenna_from_rinex_headers():
    rover = _eq("07590920_head20.05o")           # RINEX 2.10, GEONET 0759
    assert {k: rover[k] for k in ("receiver", "receiver_version", "antenna", "radome", "format", "files")} == {
        "receiver": "TRIMBLE 5700", "receiver_version": "1.24", "antenna": "TRM29659.00", "radome": None,
        "format": "RINEX 2.10", "files": ["07590920_head20.05o"]}
    base = _eq("3034265G_head5.21O")              # RINEX 3.04, GEONET 3034: a radome in columns 37-40
    assert (base["receiver"], base["receiver_version"], base["antenna"], base["radome"], base["format"]) == (
        "TRIMBLE NetR9", "5.37,21/SEP/2018", "TRM159900.00", "SCIS", "RINEX 3.04")
    assert "REC # / TYPE / VERS" in base["source"]
    sept = _eq("matrtklib_base_head4.obs")        # antenna "Unknown" in the header: not stated
    assert sept["receiver"] == "SEPT MOSAIC-X5" and sept["antenna"] is None
    assert equipment_text(base) == ("TRIMBLE NetR9 (version 5.37,21/SEP/2018), antenna TRM159900.00, radome SCIS; "
                                    "from the RINEX 3.04 header")
    assert equipment_text(sept).startswith("SEPT MOSAIC-X5 (version 4.14.4), antenna model not stated")


def test_logs_without_a_header_are_named_by_their_format():
    from georef_core.gnss.rtcm3 import decode_rtcm3_bytes
    from georef_core.gnss.rtcm3_writer import encode_rtcm3_stream
    from georef_core.gnss.rinex_obs import read_rinex_obs

    from georef_core.gnss.ubx import decode_ubx_bytes
    from tests.gnss.test_ubx import T0_TOW, WEEK, rawx, ubx as ubx_frame

    # a u-blox log without MON-VER, then with one (30-char software, 10-char hardware, 30-char extensions)
    epoch = rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 5, "sig": 0}, {"gnss": 0, "sv": 9, "sig": 0}])
    ubx = receiver_equipment(decode_ubx_bytes(epoch).observations.header, "ubx", ["flight.ubx"])
    assert ubx["receiver"] is None and ubx["format"] == "u-blox (UBX)"
    assert equipment_text(ubx) == "u-blox (UBX): receiver model not stated, antenna model not stated in the file"
    mon_ver = ubx_frame(0x0A, 0x04, b"EXT CORE 1.00 (3fda8e)".ljust(30, b"\0") + b"00190000".ljust(10, b"\0")
                        + b"FWVER=HPG 1.32".ljust(30, b"\0") + b"MOD=ZED-F9P".ljust(30, b"\0"))
    f9p = receiver_equipment(decode_ubx_bytes(mon_ver + epoch).observations.header, "ubx")
    assert (f9p["receiver"], f9p["receiver_version"]) == ("u-blox ZED-F9P", "HPG 1.32")
    assert equipment_text(f9p).startswith("u-blox ZED-F9P (version HPG 1.32), antenna model not stated; from the "
                                          "u-blox (UBX) log")
    # an RTCM 3 stream: without a 1033 message (a DJI aircraft's raw log), then with one
    raw = read_rinex_obs(RINEX / "07590920_head20.05o")
    t0 = float(raw.gps_time_s[0])
    bare = decode_rtcm3_bytes(encode_rtcm3_stream(raw), approx_gps_time_s=t0)
    dji = receiver_equipment(bare.observations.header, "rtcm3", ["DJI_001_PPKRAW.bin"], dji=True)
    assert dji["receiver"] is None and dji["format"] == "DJI RTCM 3 log"
    assert equipment_text(dji).startswith("DJI RTCM 3 log: receiver model not stated")
    full = decode_rtcm3_bytes(encode_rtcm3_stream(raw, receiver_type="SEPT ASTERX-SB",
                                                  antenna_descriptor="LEIAR25.R4      LEIT"), approx_gps_time_s=t0)
    cors = receiver_equipment(full.observations.header, "rtcm3")
    assert (cors["receiver"], cors["antenna"], cors["radome"], cors["format"]) == (
        "SEPT ASTERX-SB", "LEIAR25.R4", "LEIT", "RTCM 3 log")


@pytest.mark.skipif(__import__("shutil").which("pdftotext") is None, reason="poppler-utils not installed")
def test_report_prints_the_receivers_in_its_gnss_section(tmp_path):
    from backend.services.report_pdf import build_report

    from .test_survey_report import _meta, _run_folder, _text

    out, survey = _run_folder(tmp_path, with_rasters=False)
    summary_path = out / "ppk" / "summary.json"
    s = json.loads(summary_path.read_text())
    s["equipment"] = {"rover": _eq("07590920_head20.05o"), "base": _eq("3034265G_head5.21O")}
    summary_path.write_text(json.dumps(s))
    pdf = tmp_path / "report.pdf"
    built = build_report(out, pdf, _meta(volumes=[], stockpile_outlines=[]), survey_dir=survey)
    assert "gnss_equipment" in built["sections"]
    text = _text(pdf)
    gnss = text[text.index("GNSS trajectory (PPK)"):]
    assert "Rover (aircraft) TRIMBLE 5700 (version 1.24), antenna TRM29659.00; from the RINEX 2.10 header" in gnss
    assert ("Base station TRIMBLE NetR9 (version 5.37,21/SEP/2018), antenna TRM159900.00, radome SCIS; from the "
            "RINEX 3.04 header") in gnss
    # a run processed before the models were kept says so
    del s["equipment"]
    summary_path.write_text(json.dumps(s))
    build_report(out, pdf, _meta(volumes=[], stockpile_outlines=[]), survey_dir=survey)
    assert "Receiver and antenna models: not recorded in this run's GNSS summary." in _text(pdf)
