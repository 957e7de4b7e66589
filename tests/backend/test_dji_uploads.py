"""DJI flight folders as the aircraft writes them (photos + *_Timestamp.MRK + *_PPKRAW.bin RTCM 3 log),
uploaded as a zip or as separate files with their relative folder, several flights per survey and base
data in several files: stored in flights/<flight folder>/ and named by the pre-flight ("2 flights, 8 photos,
MRK 8 exposures, 2 RTCM 3 rover logs, base: 3 RINEX files, no navigation file needed"), with the bad
inputs (MRK that does not match the photos in count or time, a PPKRAW without ephemerides and no
navigation file, photos of two aircraft mixed, a damaged MRK) each a clear error or warning naming the
files, and nothing already uploaded lost.

The files are made here: tiny JPEGs with EXIF (PIL), MRK text, RTCM 3 frames built bit by bit (MSM4 GPS
epochs, 1019/1045 ephemerides). One test also reads the start of a real Phantom 4 RTK PPKRAW.bin from
the shared data (skipped when absent)."""

from __future__ import annotations

import io
import zipfile
from datetime import datetime, timedelta
from pathlib import Path

import pytest

from .platform_helpers import Api, add_user, upload_bytes

WEEK = 2024                      # 2018-10-21 .. 27, as the real Phantom 4 RTK log
SOW0 = 300000.0                  # 2018-10-24 11:20:00 GPS
GPS_EPOCH = datetime(1980, 1, 6)
REAL_PPKRAW = Path("/work/shared/data/dji/p4rtk_auckland_2018/100_0004_PPKRAW.bin")


def gps_dt(sow: float) -> datetime:
    return GPS_EPOCH + timedelta(seconds=WEEK * 604800 + sow)


# ----------------------------------------------------------------------------------------------- files


def _bits(*fields: tuple[int, int], size: int | None = None) -> bytes:
    s = "".join(format(v & ((1 << n) - 1), f"0{n}b") for v, n in fields)
    s += "0" * (-len(s) % 8)
    out = int(s, 2).to_bytes(len(s) // 8, "big")
    return out + bytes((size or 0) - len(out)) if size else out


def _frame(payload: bytes) -> bytes:
    from georef_core.gnss.rtcm3_writer import frame_rtcm3

    return frame_rtcm3(payload)


def msm4_gps(tow_ms: int, prn: int = 5) -> bytes:
    """An MSM4 GPS message: one satellite, one signal (1C)."""
    return _frame(_bits((1074, 12), (0, 12), (tow_ms, 30), (0, 1), (0, 3), (0, 7), (0, 2), (0, 2), (0, 1), (0, 3),
                        (1 << (64 - prn), 64), (1 << (32 - 2), 32), (1, 1), (70, 8), (512, 10),
                        (100, 15), (200, 22), (9, 4), (0, 1), (45, 6)))


def eph_1019(sat: int) -> bytes:
    return _frame(_bits((1019, 12), (sat, 6), (WEEK % 1024, 10), size=61))


def eph_1045(sat: int) -> bytes:
    return _frame(_bits((1045, 12), (sat, 6), (WEEK - 1024, 12), size=62))


def ppkraw(sow_start: float, seconds: int, gps_eph: int = 6, galileo_eph: int = 1) -> bytes:
    """An RTCM 3 raw log: ephemerides first, then a GPS MSM4 epoch per second; DJI's own records
    (junk bytes) between frames, as in a real PPKRAW.bin."""
    out = b"".join(eph_1019(s) for s in range(1, gps_eph + 1)) + b"".join(eph_1045(s) for s in range(1, galileo_eph + 1))
    for k in range(seconds + 1):
        out += msm4_gps(int(round((sow_start + k) * 1000))) + (b"\x55\xaa\x01\x02" if k % 7 == 0 else b"")
    return out


def mrk_text(sows: list[float], first_index: int = 1) -> bytes:
    lines = []
    for i, t in enumerate(sows):
        lines.append(f"{first_index + i}\t{t:.6f}\t[{WEEK}]\t   -26,N\t    19,E\t   191,V\t-36.4114{i:04d},Lat\t"
                     f"174.630{i:05d},Lon\t170.415,Ellh\t0.012, 0.011, 0.025\t50,Q")
    return ("\n".join(lines) + "\n").encode()


def jpeg(when: datetime, model: str = "FC6310R", size: tuple[int, int] = (64, 48)) -> bytes:
    """A tiny JPEG with the EXIF a DJI camera writes: make, model, DateTimeOriginal (local time)."""
    from PIL import Image

    ex = Image.Exif()
    ex[271], ex[272] = "DJI", model
    ifd = ex.get_ifd(0x8769)
    ifd[36867] = when.strftime("%Y:%m:%d %H:%M:%S")
    buf = io.BytesIO()
    Image.new("RGB", size, (90, 120, 60)).save(buf, "JPEG", exif=ex, quality=50)
    return buf.getvalue()


def flight(name: str, sow0: float, n_photos: int = 4, n_exposures: int | None = None, step_s: float = 3.0,
           models: dict[int, str] | None = None, exif_shift_s: dict[int, float] | None = None,
           log: bytes | None = None) -> dict[str, bytes]:
    """The files of one DJI flight folder: DJI_0001.JPG ..., <name>_Timestamp.MRK, <name>_PPKRAW.bin."""
    n_exp = n_photos if n_exposures is None else n_exposures
    sows = [sow0 + step_s * k for k in range(n_exp)]
    out = {}
    for k in range(n_photos):
        # the camera clock: local time (UTC+13) of the GPS time less the 18 leap seconds, whole seconds
        t = gps_dt(sows[min(k, n_exp - 1)] + (exif_shift_s or {}).get(k, 0.0)) + timedelta(hours=13, seconds=-18)
        out[f"DJI_{k + 1:04d}.JPG"] = jpeg(t.replace(microsecond=0), (models or {}).get(k, "FC6310R"))
    out[f"{name}_Timestamp.MRK"] = mrk_text(sows)
    out[f"{name}_PPKRAW.bin"] = log if log is not None else ppkraw(sow0 - 10, int(step_s * n_exp) + 20)
    out[f"{name}_EVENTLOG.bin"] = bytes(range(256)) * 4      # DJI's undocumented log: not survey input
    return out


def rinex_obs(sow_first: float, sow_last: float, interval: float = 30.0, marker: str = "BASE") -> bytes:
    t0 = gps_dt(sow_first)
    head = [
        f"{3.04:9.2f}{'':11s}{'OBSERVATION DATA':20s}{'G (GPS)':20s}RINEX VERSION / TYPE",
        f"{marker:60s}MARKER NAME",
        f"{-5105681.0:14.4f}{461564.0:14.4f}{-3782181.0:14.4f}{'':18s}APPROX POSITION XYZ",
        f"{'G    2 C1C L1C':60s}SYS / # / OBS TYPES",
        f"{interval:10.3f}{'':50s}INTERVAL",
        f"{t0.year:6d}{t0.month:6d}{t0.day:6d}{t0.hour:6d}{t0.minute:6d}{t0.second:13.7f}     GPS         TIME OF FIRST OBS",
        f"{'':60s}END OF HEADER",
    ]
    lines = list(head)
    t = sow_first
    while t <= sow_last + 1e-6:
        d = gps_dt(t)
        lines.append(f"> {d.year:4d} {d.month:02d} {d.day:02d} {d.hour:02d} {d.minute:02d}"
                     f"{d.second + d.microsecond / 1e6:11.7f}  0  1")
        lines.append("G05  21000000.000   110000000.000  ")
        t += interval
    return ("\n".join(lines) + "\n").encode()


def zip_of(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


# ----------------------------------------------------------------------------------------------- API


@pytest.fixture(scope="module")
def api(platform):
    add_user(platform, f"dji-{platform.shape}@example.org", org_admin=True)
    a = Api(platform, f"dji-{platform.shape}@example.org")
    site = a.post("/api/v1/sites", json={"name": "DJI", "crs": "EPSG:2193"}).json()
    a.site_id, a.platform = site["id"], platform
    return a


def new_survey(api, name: str) -> str:
    r = api.post(f"/api/v1/sites/{api.site_id}/surveys", json={"name": name})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def files_of(api, sid) -> dict[str, dict]:
    return {f["path"]: f for f in api.get(f"/api/v1/surveys/{sid}/files").json()}


def check(api, sid) -> tuple[dict, dict]:
    c = api.get(f"/api/v1/surveys/{sid}/check").json()
    return c, {p["code"]: p for p in c["problems"]}


def ok(r):
    assert r.status_code == 200, r.text
    return r.json()


def refused(r, *words):
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    for w in words:
        assert w.lower() in detail.lower(), detail
    return detail


def upload_three_bases(api, sid):
    """Hourly-style base files with a 600 s gap before the flights (b1 -> b2) and none after (b2 -> b3)."""
    for name, (a, b) in {"base_1.obs": (SOW0 - 1200, SOW0 - 630), "base_2.obs": (SOW0 - 30, SOW0 + 360),
                         "base_3.obs": (SOW0 + 390, SOW0 + 1200)}.items():
        ok(upload_bytes(api, sid, name, rinex_obs(a, b), kind="base"))


# ----------------------------------------------------------------------------------------------- tests


def test_two_flights_zip_and_three_base_files(api, tmp_path):
    sid = new_survey(api, "two flights, zip")
    files = {f"DCIM/100_0004/{k}": v for k, v in flight("100_0004", SOW0).items()}
    files |= {f"DCIM/100_0005/{k}": v for k, v in flight("100_0005", SOW0 + 609).items()}
    res = ok(upload_bytes(api, sid, "sd_card.zip", zip_of(files)))["result"]
    placed = {f["path"]: f for f in res["files"]}
    for fl in ("100_0004", "100_0005"):
        assert {f"flights/{fl}/DJI_000{k}.JPG" for k in range(1, 5)} <= set(placed)
        assert placed[f"flights/{fl}/{fl}_Timestamp.MRK"]["kind"] == "dji-mrk"
        log = placed[f"flights/{fl}/{fl}_PPKRAW.bin"]
        assert (log["kind"], log["role"]) == ("rtcm3", "rover")
    assert {i["name"] for i in res["ignored"]} == {"DCIM/100_0004/100_0004_EVENTLOG.bin",
                                                   "DCIM/100_0005/100_0005_EVENTLOG.bin"}
    meta = files_of(api, sid)
    m = meta["flights/100_0004/100_0004_Timestamp.MRK"]["meta"]
    assert (m["exposures"], m["gps_week"], m["quality_counts"]) == (4, WEEK, {"50": 4})
    assert m["first_gps_time_s"] == WEEK * 604800 + SOW0
    r3 = meta["flights/100_0004/100_0004_PPKRAW.bin"]["meta"]
    assert r3["systems"] == ["G"] and r3["ephemeris_satellites"] == {"G": 6, "E": 1} and r3["msm_messages"] == 33
    assert r3["first_gps_time_s"] == WEEK * 604800 + SOW0 - 10 and r3["time_reference"] == "Galileo ephemeris week"
    img = meta["flights/100_0004/DJI_0001.JPG"]["meta"]
    assert (img["make"], img["model"], img["time_original"]) == ("DJI", "FC6310R", "2018-10-25T00:19:42")

    c, codes = check(api, sid)
    assert codes["missing-base"]["severity"] == "error"
    upload_three_bases(api, sid)
    c, codes = check(api, sid)
    assert c["errors"] == 0, c
    assert c["summary"] == ("2 flights, 8 photos, MRK 8 exposures, 2 RTCM 3 rover logs, base: 3 RINEX files, "
                            "no navigation file needed")
    assert codes["base-files-joined"]["message"].startswith(
        "base: 3 RINEX files, 2018-10-24 11:00-11:40, gap of 600 s between base_1.obs and base_2.obs")
    assert "base-gap" not in codes                         # the gap is before the flights
    assert "gap of 600 s between 100_0004 and 100_0005" in codes["flights-joined"]["message"]
    assert codes["rover-files-joined"]["message"].startswith("rover: 2 RTCM 3 logs, 2018-10-24 11:19-11:30")
    assert "several-rover-files" not in codes and "several-base-files" not in codes
    assert not {"missing-navigation", "no-time-overlap", "partial-time-overlap", "mrk-photo-mismatch"} & set(codes)
    # the worker's survey folder of the gnss step, read by the pipeline: two DJI flights joined, their
    # photos tied to their MRK by folder, the three base files
    found = materialised_inputs(api, sid, tmp_path)
    assert found.layout == "dji" and [f.folder.name for f in found.flights] == ["100_0004", "100_0005"]
    assert len(found.image_names) == 8 and [p.name for p in found.rover_files] == ["100_0004_PPKRAW.bin",
                                                                                 "100_0005_PPKRAW.bin"]
    assert sorted(p.name for p in found.base_files) == ["base_1.obs", "base_2.obs", "base_3.obs"]
    assert any("600 s between flights 100_0004 and 100_0005" in w for w in found.warnings)


def materialised_inputs(api, sid, tmp_path):
    """The survey folder the worker builds for the gnss step (worker.tasks.materialise from the stored
    files), read by georef_core.steps.survey_inputs."""
    from backend.storage import storage_for
    from georef_core.steps.survey_inputs import survey_inputs
    from worker.tasks import materialise

    run = {"inputs": {p: f["sha256"] for p, f in files_of(api, sid).items()}, "outputs": [],
           "site": {"crs": "EPSG:2193"}}
    survey_dir, out_dir = materialise(storage_for(api.platform.settings), run, "gnss", tmp_path / "run")
    return survey_inputs(survey_dir, out_dir)


def test_flight_files_sent_one_by_one_with_their_folder(api):
    sid = new_survey(api, "one by one")
    files = flight("100_0006", SOW0)
    for name, data in files.items():
        if name.endswith("EVENTLOG.bin"):
            refused(upload_bytes(api, sid, name, data, kind="flight", folder="DCIM/100_0006"), "binary data")
        elif name.endswith(".MRK"):    # no kind: recognised by content, its folder named by the DJI file name
            r = ok(upload_bytes(api, sid, name, data))
            assert r["result"]["files"][0]["path"] == "flights/100_0006/100_0006_Timestamp.MRK"
        else:
            r = ok(upload_bytes(api, sid, name, data, kind="flight", folder="DCIM/100_0006"))
            assert r["folder"] == "DCIM/100_0006"
            assert r["result"]["files"][0]["path"] == f"flights/100_0006/{name}"
    # kind=flight needs the folder (a photo's name does not say its flight)
    r = api.post(f"/api/v1/surveys/{sid}/uploads", json={"filename": "DJI_0009.JPG", "size": 10, "sha256": "a" * 64,
                                                         "kind": "flight"})
    assert r.status_code == 422 and "folder" in r.json()["detail"]
    # an MRK with neither folder nor a DJI name cannot be tied to its photos
    refused(upload_bytes(api, sid, "exposures.txt", mrk_text([SOW0])), "belongs with its flight's photos")
    # the raw log of a flight is the rover's: it cannot be moved to base/
    log = files_of(api, sid)["flights/100_0006/100_0006_PPKRAW.bin"]
    r = api.patch(f"/api/v1/surveys/{sid}/files/{log['id']}", json={"role": "base"})
    assert r.status_code == 422 and "DJI flight" in r.json()["detail"]
    ok(upload_bytes(api, sid, "cors.obs", rinex_obs(SOW0 - 60, SOW0 + 60), kind="base"))
    c, codes = check(api, sid)
    assert c["ok"], c
    assert c["summary"] == ("1 flight, 4 photos, MRK 4 exposures, RTCM 3 rover log, base: 1 RINEX file, "
                            "no navigation file needed")
    # a zip of the flight folder alone (wrapper folder = the flight's name) lands in the same place
    sid2 = new_survey(api, "one flight zip")
    res = ok(upload_bytes(api, sid2, "100_0006.zip", zip_of({f"100_0006/{k}": v for k, v in files.items()})))
    assert {f["path"] for f in res["result"]["files"]} == {f"flights/100_0006/{k}" for k in files
                                                           if not k.endswith("EVENTLOG.bin")}


def test_rtcm3_kinds_for_rover_base_and_nav(api):
    sid = new_survey(api, "rtcm3 roles")
    log = ppkraw(SOW0, 30)
    assert ok(upload_bytes(api, sid, "drtk2.bin", log, kind="base"))["result"]["files"][0]["path"] == "base/drtk2.bin"
    assert ok(upload_bytes(api, sid, "eph.rtcm3", log, kind="nav"))["result"]["files"][0]["path"] == "nav/eph.rtcm3"
    f = ok(upload_bytes(api, sid, "m4.rtk", log, kind="rover"))["result"]["files"][0]
    assert (f["path"], f["kind"], f["role"]) == ("rover/m4.rtk", "rtcm3", "rover")
    # a DJI MRK is not a rover log
    refused(upload_bytes(api, sid, "x_Timestamp.MRK", mrk_text([SOW0]), kind="rover"),
            "DJI Timestamp.MRK", "kind=rover")
    c, _ = check(api, sid)
    assert c["ok"], c["problems"]
    assert c["summary"] == ("no photos, RTCM 3 rover log, base: 1 RTCM 3 log, no navigation file needed")


def test_bad_dji_inputs_named(api, tmp_path):
    sid = new_survey(api, "bad inputs")
    upload_three_bases(api, sid)
    # count: 4 photos, 3 exposures -> the MRK does not belong to these photos
    fa = flight("A", SOW0, n_photos=4, n_exposures=3)
    # more exposures than photos: a warning (deleted photos)
    fb = flight("B", SOW0 + 100, n_photos=3, n_exposures=5)
    # photo times do not follow the MRK times
    fc = flight("C", SOW0 + 200, exif_shift_s={2: 12.0})
    # photos of two aircraft mixed in one folder
    fd = flight("D", SOW0 + 300, models={1: "FC6310S", 3: "FC6310S"})
    zipped = {f"{n}/{k}": v for n, fl in (("A", fa), ("B", fb), ("C", fc), ("D", fd)) for k, v in fl.items()}
    ok(upload_bytes(api, sid, "bad.zip", zip_of(zipped)))
    c, codes = check(api, sid)
    assert not c["ok"]
    e = codes["mrk-photo-mismatch"]
    assert e["severity"] == "error" and e["message"].startswith(
        "A_Timestamp.MRK: 3 exposures but 4 photos in flights/A (no exposure for DJI_0004.JPG)")
    assert "flights/A/A_Timestamp.MRK" in e["files"]
    w = codes["exposures-without-photos"]
    assert w["severity"] == "warning" and "B_Timestamp.MRK: 2 of 5 exposures have no photo in flights/B" in w["message"]
    t = codes["mrk-photo-time-mismatch"]
    assert t["severity"] == "error" and "C_Timestamp.MRK" in t["message"] and "flights/C" in t["message"]
    assert "varies by 12.0 s" in t["message"]
    m = codes["mixed-cameras"]
    assert m["severity"] == "error" and "flights/D" in m["message"] and "FC6310S" in m["message"]
    assert {"flights/D/DJI_0002.JPG", "flights/D/DJI_0001.JPG"} <= set(m["files"])
    assert "photos from two aircraft" in m["message"]
    assert c["summary"].startswith("4 flights, 15 photos, MRK 16 exposures, 4 RTCM 3 rover logs")
    # what the pre-flight calls an error stops the pipeline too
    from georef_core.errors import InputFileError

    with pytest.raises(InputFileError, match="more than one camera"):
        materialised_inputs(api, sid, tmp_path)


def test_ppkraw_without_ephemerides(api):
    sid = new_survey(api, "no ephemerides")
    upload_three_bases(api, sid)
    ok(upload_bytes(api, sid, "f.zip", zip_of({f"F/{k}": v for k, v in
                                               flight("F", SOW0, log=ppkraw(SOW0 - 10, 30, 0, 0)).items()})))
    c, codes = check(api, sid)
    e = codes["missing-navigation"]
    assert e["severity"] == "error" and e["message"].startswith("PPKRAW without ephemerides and no navigation file")
    assert e["files"] == ["flights/F/F_PPKRAW.bin"] and "F_PPKRAW.bin carries no ephemeris" in e["message"]
    assert c["summary"].endswith("base: 3 RINEX files, no navigation file")
    # without a week (no ephemeris) the log is dated by its flight's MRK: the overlap is still checked
    meta = files_of(api, sid)["flights/F/F_PPKRAW.bin"]["meta"]
    assert "first_gps_time_s" not in meta and meta["first_tow_s"] == SOW0 - 10
    assert "time-span-unknown" not in codes and "no-time-overlap" not in codes
    # a navigation file clears it
    from georef_core.gnss.input_files import sniff_bytes

    nav = (f"{3.04:9.2f}{'':11s}{'N: GNSS NAV DATA':20s}{'G: GPS':20s}RINEX VERSION / TYPE\n"
           f"{'':60s}END OF HEADER\n").encode()
    assert sniff_bytes(nav) == "rinex-nav"
    ok(upload_bytes(api, sid, "brdc.nav", nav))
    c, codes = check(api, sid)
    assert "missing-navigation" not in codes and c["ok"], c
    assert c["summary"].endswith("base: 3 RINEX files, navigation: 1 RINEX file")


def test_rtk_photos_alone(api):
    """A flight flown with RTK on (photos + MRK, no raw log) and no base: no PPK, not an error."""
    sid = new_survey(api, "RTK photos alone")
    files = {f"DCIM/100_0007/{k}": v for k, v in flight("100_0007", SOW0).items() if not k.endswith(".bin")}
    ok(upload_bytes(api, sid, "rtk.zip", zip_of(files)))
    c, codes = check(api, sid)
    assert c["ok"], c["problems"]
    assert codes["photos-only"]["severity"] == "warning"
    assert not {"missing-rover", "missing-base", "missing-navigation"} & set(codes)
    assert c["summary"] == "1 flight, 4 photos, MRK 4 exposures, no rover log, no base, photo positions only (no PPK)"


def test_few_ephemerides_warned(api):
    sid = new_survey(api, "few ephemerides")
    upload_three_bases(api, sid)
    ok(upload_bytes(api, sid, "f.zip", zip_of({f"F/{k}": v for k, v in
                                               flight("F", SOW0, log=ppkraw(SOW0 - 10, 30, 2, 1)).items()})))
    c, codes = check(api, sid)
    w = codes["few-ephemerides"]
    assert w["severity"] == "warning" and "GPS 2" in w["message"] and w["files"] == ["flights/F/F_PPKRAW.bin"]
    assert c["ok"] and "navigation file advised" in c["summary"]


def test_damaged_mrk_refused_and_nothing_lost(api):
    sid = new_survey(api, "damaged")
    good = flight("G", SOW0)
    ok(upload_bytes(api, sid, "g.zip", zip_of({f"G/{k}": v for k, v in good.items()})))
    before = {p: f["sha256"] for p, f in files_of(api, sid).items()}
    lines = good["G_Timestamp.MRK"].decode().splitlines()
    lines[2] = lines[2].replace(",Lat", ",Lax")
    damaged = ("\n".join(lines) + "\n").encode()
    refused(upload_bytes(api, sid, "G_Timestamp.MRK", damaged, kind="flight", folder="G"),
            "damaged DJI Timestamp.MRK, line 3", "Lax")
    refused(upload_bytes(api, sid, "g2.zip", zip_of({f"G/{k}": (damaged if k.endswith(".MRK") else v)
                                                     for k, v in good.items()})), "G/G_Timestamp.MRK", "line 3")
    two = zip_of({"G/a_Timestamp.MRK": good["G_Timestamp.MRK"], "G/b_Timestamp.MRK": good["G_Timestamp.MRK"],
                  "G/DJI_0001.JPG": good["DJI_0001.JPG"]})
    refused(upload_bytes(api, sid, "g3.zip", two), "2 Timestamp.MRK files", "own folder")
    # a photo declared as a flight file of the wrong kind, a GNSS log as a photo
    refused(upload_bytes(api, sid, "G_PPKRAW.bin", good["G_PPKRAW.bin"], kind="images"), "RTCM 3 log", "kind=images")
    after = {p: f["sha256"] for p, f in files_of(api, sid).items()}
    assert after == before
    # a flight folder without its MRK is named
    ok(upload_bytes(api, sid, "DJI_0001.JPG", good["DJI_0001.JPG"], kind="flight", folder="DCIM/H"))
    c, codes = check(api, sid)
    assert codes["flight-without-mrk"]["message"].startswith("flights/H has 1 photo and 0 raw logs but no Timestamp.MRK")


def test_real_ppkraw_head(api):
    if not REAL_PPKRAW.is_file():
        pytest.skip("shared DJI data not present")
    from georef_core.gnss.rtcm3 import find_rtcm3_frames

    data = REAL_PPKRAW.read_bytes()[:40000]
    fr = find_rtcm3_frames(data)
    head = data[:int(fr.start[-1] + fr.length[-1] + 6)]        # cut at a frame boundary
    sid = new_survey(api, "real head")
    f = ok(upload_bytes(api, sid, "100_0004_PPKRAW.bin", head, kind="flight", folder="100_0004"))["result"]["files"][0]
    assert (f["path"], f["kind"], f["role"]) == ("flights/100_0004/100_0004_PPKRAW.bin", "rtcm3", "rover")
    meta = files_of(api, sid)[f["path"]]["meta"]
    assert meta["systems"] == ["G", "R", "E", "C"] and meta["ephemeris_messages"] == 0
    assert meta["message_counts"]["1075"] == 64 and meta["interval_s"] == 0.2
    assert meta["first_tow_s"] == pytest.approx(275287.6)
    c, codes = check(api, sid)
    assert codes["flight-without-mrk"]["severity"] == "error"


def test_rtcm3_scan_in_pieces_counts_the_same(tmp_path, monkeypatch):
    from backend.services import file_kinds

    p = tmp_path / "log.bin"
    p.write_bytes(ppkraw(SOW0, 400))
    whole = file_kinds.recognise(p)
    assert whole.kind == "rtcm3" and whole.meta["epochs"] == 401
    for piece in (700, 4096, 9999):
        monkeypatch.setattr(file_kinds, "RTCM3_SCAN_BYTES", piece)
        assert file_kinds.recognise(p).meta == whole.meta
