"""What a survey folder holds (georef_core.steps.survey_inputs): DJI flight folders recognised by content,
photos tied to MRK exposures, several flights joined, and the bad inputs named: an MRK that does not
belong to its photos (count, time), two cameras in one flight, a raw log without ephemerides and no
navigation file. Plus the RTCM 3 path on real data: the GSI baseline's rover written as an RTCM 3 raw
log beside an MRK solves like its RINEX file."""

from __future__ import annotations

import datetime as dt
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from georef_core.errors import InputFileError
from georef_core.gnss.gnss_time import gps_time_s_to_datetime, gps_time_s_to_week_tow, leap_seconds_at
from georef_core.steps.survey_inputs import read_camera_offsets, survey_inputs

GSI = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"
T0 = 1_400_000_000.0          # a GPS time for the synthetic flights


def _jpeg(path: Path, exif_time_gps_s: float | None = None, model: str = "FC6310R", size=(64, 48)) -> None:
    import piexif

    exif = {"0th": {piexif.ImageIFD.Make: b"DJI", piexif.ImageIFD.Model: model.encode()}, "Exif": {}}
    if exif_time_gps_s is not None:
        utc = gps_time_s_to_datetime(exif_time_gps_s)
        local = utc - dt.timedelta(seconds=leap_seconds_at(utc)) + dt.timedelta(hours=13)   # a local clock
        exif["Exif"][piexif.ExifIFD.DateTimeOriginal] = local.strftime("%Y:%m:%d %H:%M:%S").encode()
    Image.new("RGB", size, (90, 120, 60)).save(path, "JPEG", exif=piexif.dump(exif))


def _mrk_line(i: int, t: float, off_mm=(12, -5, 190)) -> str:
    week, sow = gps_time_s_to_week_tow(t)
    return (f"{i}\t{sow:.6f}\t[{week}]\t{off_mm[0]:6d},N\t{off_mm[1]:6d},E\t{off_mm[2]:6d},V\t35.13000000,Lat\t"
            f"136.97000000,Lon\t120.000,Ellh\t0.010000, 0.010000, 0.015000\t50,Q")


def _flight(folder: Path, times: list[float], n_photos: int | None = None, exif_shift=None, stem="DJI_0001",
            models=None) -> Path:
    folder.mkdir(parents=True)
    n_photos = len(times) if n_photos is None else n_photos
    for i in range(n_photos):
        t = times[i] if i < len(times) else times[-1] + 2.0 * (i - len(times) + 1)
        shift = (exif_shift or {}).get(i, 0.0)
        _jpeg(folder / f"DJI_{i + 1:04d}.JPG", t + shift, (models or {}).get(i, "FC6310R"))
    (folder / f"{stem}_Timestamp.MRK").write_text("\n".join(_mrk_line(i + 1, t) for i, t in enumerate(times)) + "\n")
    return folder


def test_standard_layout_unchanged(tmp_path):
    (tmp_path / "images").mkdir()
    _jpeg(tmp_path / "images" / "a.jpg")
    found = survey_inputs(tmp_path, tmp_path / "out")
    assert found.layout == "standard" and found.image_names == ["a.jpg"] and found.events_csv is None


def test_dji_flight_folder_found_by_content(tmp_path):
    survey = tmp_path / "s"
    times = [T0 + 2.0 * k for k in range(4)]
    _flight(survey / "DCIM" / "100_0042", times, stem="100_0042")
    (survey / "DCIM" / "100_0042" / "100_0042_Timestamp.MRK").rename(survey / "DCIM" / "100_0042" / "anything.txt")
    found = survey_inputs(survey, tmp_path / "out")
    assert found.layout == "dji" and len(found.flights) == 1 and found.flights[0].mrk_path.name == "anything.txt"
    assert found.image_names == [f"DJI_{k:04d}.JPG" for k in range(1, 5)]
    assert all((found.image_dir / n).is_file() for n in found.image_names)
    ev = np.genfromtxt(found.events_csv, delimiter=",", names=True, dtype=None, encoding=None)
    np.testing.assert_allclose(ev["gps_time_s"], times, atol=1e-6)
    off = read_camera_offsets(found.camera_offsets_csv)
    np.testing.assert_allclose(off["DJI_0002.JPG"], [0.012, -0.005, 0.190])


def test_two_flights_joined_with_the_gap_named_and_names_kept_apart(tmp_path):
    survey = tmp_path / "s"
    _flight(survey / "DJI_202401011000_001", [T0 + 2.0 * k for k in range(3)], stem="F1")
    _flight(survey / "DJI_202401011030_002", [T0 + 900.0 + 2.0 * k for k in range(3)], stem="F2")
    found = survey_inputs(survey, tmp_path / "out")
    assert len(found.flights) == 2 and len(found.image_names) == 6
    assert found.image_names[0].startswith("DJI_202401011000_001_")       # both flights have DJI_0001.JPG
    assert any("896 s between flights" in w for w in found.warnings), found.warnings


def test_mrk_that_does_not_belong_to_its_photos(tmp_path):
    times = [T0 + 2.0 * k for k in range(3)]
    # more photos than exposures: refused, naming the MRK and the folder
    f = _flight(tmp_path / "a" / "flight", times[:2], n_photos=3)
    with pytest.raises(InputFileError, match=r"2 exposures but 3 photos .*flight.*does not belong") as exc:
        survey_inputs(tmp_path / "a", tmp_path / "out_a")
    assert "Timestamp.MRK" in str(exc.value) and str(f) in str(exc.value)
    # more exposures than photos (deleted photos): a warning
    _flight(tmp_path / "b" / "flight", times + [T0 + 6.0], n_photos=3)
    found = survey_inputs(tmp_path / "b", tmp_path / "out_b")
    assert any("1 exposure(s) without a photo" in w for w in found.warnings)
    # times that do not follow the photos' EXIF times (another flight's MRK)
    _flight(tmp_path / "c" / "flight", times, exif_shift={2: 40.0})
    with pytest.raises(InputFileError, match="EXIF times do not follow the MRK times"):
        survey_inputs(tmp_path / "c", tmp_path / "out_c")


def test_two_cameras_in_one_flight_refused(tmp_path):
    _flight(tmp_path / "s" / "flight", [T0, T0 + 2.0, T0 + 4.0], models={1: "L1D-20c"})
    with pytest.raises(InputFileError, match=r"photos from more than one camera.*DJI_0002.JPG"):
        survey_inputs(tmp_path / "s", tmp_path / "out")


# ------------------------------------------------------------------------------- the RTCM 3 path, real data
def _gsi_dji_survey(tmp_path: Path, with_ephemerides: bool, with_nav: bool) -> Path:
    from georef_core.gnss.input_files import load_navigation
    from georef_core.gnss.rinex_obs import read_rinex_obs
    from georef_core.gnss.rtcm3_writer import encode_rtcm3_stream

    rover = read_rinex_obs(GSI / "07590920.05o")
    nav = load_navigation([GSI / "07590920.05n"])
    survey = tmp_path / "site"
    times = [float(rover.gps_time_s[10]) + 30.0 * k + 7.5 for k in range(3)]
    flight = _flight(survey / "DJI_200504020000_001", times, stem="DJI_200504020000_001")
    (flight / "DJI_200504020000_001_PPKRAW.bin").write_bytes(
        encode_rtcm3_stream(rover, nav if with_ephemerides else None, msm=7))
    (survey / "base").mkdir()
    shutil.copy(GSI / "30400920.05o", survey / "base")
    if with_nav:
        (survey / "nav").mkdir()
        shutil.copy(GSI / "30400920.05n", survey / "nav")
    return survey


def test_raw_log_without_ephemerides_and_no_nav_is_named(tmp_path):
    from georef_core.steps.gnss_solve import run_survey_gnss

    survey = _gsi_dji_survey(tmp_path, with_ephemerides=False, with_nav=False)
    with pytest.raises(InputFileError, match=r"no navigation data: the observation files .*PPKRAW.bin.*30400920.05o"
                                             r".* carry no ephemerides and no navigation file was given"):
        run_survey_gnss(survey, tmp_path / "out")


def test_rtcm3_raw_log_solves_like_its_rinex(tmp_path):
    """The same real rover (GSI 0759, static, L1/L2) as RINEX in rover/ + events.csv and as an RTCM 3 MSM7
    raw log (with its ephemerides, no navigation file) beside an MRK: the antenna positions at the three
    exposures agree within 1 mm (MSM7 keeps pseudoranges to 0.3 mm and phases to 0.07 mm)."""
    from georef_core.steps.gnss_solve import run_survey_gnss

    dji = _gsi_dji_survey(tmp_path / "dji", with_ephemerides=True, with_nav=False)
    s_dji = run_survey_gnss(dji, tmp_path / "out_dji")
    assert s_dji["inputs"]["layout"] == "dji" and s_dji["events"]["count"] == 3
    std = tmp_path / "std"
    for sub in ("rover", "base", "nav"):
        (std / sub).mkdir(parents=True)
    shutil.copy(GSI / "07590920.05o", std / "rover")
    shutil.copy(GSI / "30400920.05o", std / "base")
    shutil.copy(GSI / "07590920.05n", std / "nav")
    ev = np.genfromtxt(tmp_path / "out_dji" / "inputs" / "events.csv", delimiter=",", names=True, dtype=None,
                       encoding=None)
    (std / "events.csv").write_text("gps_time_s\n" + "\n".join(f"{t:.6f}" for t in ev["gps_time_s"]) + "\n")
    s_std = run_survey_gnss(std, tmp_path / "out_std")
    assert s_std["fix_rate"] == pytest.approx(s_dji["fix_rate"], abs=0.02)
    a = np.genfromtxt(tmp_path / "out_dji" / "ppk" / "events.csv", delimiter=",", names=True)
    b = np.genfromtxt(tmp_path / "out_std" / "ppk" / "events.csv", delimiter=",", names=True)
    d = np.stack([a[c] - b[c] for c in ("x_ecef_m", "y_ecef_m", "z_ecef_m")], axis=1)
    assert np.abs(d).max() < 1e-3, d
    json.dumps(s_dji)      # the summary stays JSON
    # the receivers as the files state them: the RINEX header's models, the aircraft's log by its format
    assert s_std["equipment"]["rover"]["receiver"] == "TRIMBLE 5700"
    assert s_std["equipment"]["base"]["antenna"] == s_dji["equipment"]["base"]["antenna"] == "TRM29659.00"
    assert s_dji["equipment"]["rover"]["format"] == "DJI RTCM 3 log" and s_dji["equipment"]["rover"]["receiver"] is None


def test_mrk_apart_from_its_photos_in_the_standard_folders(tmp_path):
    """The MRK and raw log uploaded into rover/, the photos into images/: still one DJI flight."""
    times = [T0 + 2.0 * k for k in range(3)]
    _flight(tmp_path / "s" / "images", times)
    (tmp_path / "s" / "rover").mkdir()
    (tmp_path / "s" / "images" / "DJI_0001_Timestamp.MRK").rename(tmp_path / "s" / "rover" / "f_Timestamp.MRK")
    found = survey_inputs(tmp_path / "s", tmp_path / "out")
    assert found.layout == "dji" and found.image_names == ["DJI_0001.JPG", "DJI_0002.JPG", "DJI_0003.JPG"]


@pytest.mark.parametrize("content, problem", [("[" * 50000 + "]" * 50000, "JSON nested too deeply"),
                                              ("[1, 2]", "expected a JSON object"),
                                              ("{'a': 1}", "not valid JSON")])
def test_bad_survey_json_is_named(tmp_path, content, problem):
    from georef_core.steps.gnss_solve import read_survey_json

    (tmp_path / "survey.json").write_text(content)
    with pytest.raises(InputFileError, match=f"survey.json: {problem}"):
        read_survey_json(tmp_path)


def test_a_rover_cut_mid_record_is_named_in_the_solution(tmp_path):
    """A rover file cut inside an epoch record: the solve keeps the complete epochs and its warnings (the
    step summary, the UI) say the file is truncated."""
    from georef_core.steps.gnss_solve import run_survey_gnss

    for sub in ("rover", "base", "nav"):
        (tmp_path / sub).mkdir()
    data = (GSI / "07590920.05o").read_bytes()
    (tmp_path / "rover" / "rover.obs").write_bytes(data[: len(data) // 2])
    shutil.copy(GSI / "30400920.05o", tmp_path / "base")
    shutil.copy(GSI / "07590920.05n", tmp_path / "nav")
    s = run_survey_gnss(tmp_path, tmp_path / "out")
    assert s["epochs"] < 120
    assert any("rover:" in w and "ends inside this epoch record (truncated file?)" in w for w in s["warnings"]), \
        s["warnings"]


def test_dji_flight_with_a_base_but_no_raw_log_skips_ppk_with_a_warning(tmp_path):
    """A DJI RTK flight folder (photos + MRK, no *_PPKRAW.bin) beside a base: nothing to solve (PPK needs the
    drone's raw log too); the GNSS step says so and leaves the photos' positions to the georef step, where
    it used to fail with 'no rover observation file'."""
    from georef_core.steps.gnss_solve import run_survey_gnss

    survey = tmp_path / "survey"
    _flight(survey / "flight1", [T0 + 2.0 * i for i in range(4)])
    (survey / "base").mkdir()
    shutil.copy(GSI / "30400920.05o", survey / "base")
    s = run_survey_gnss(survey, tmp_path / "out")
    assert s["skipped"] is True and "a base alone cannot be solved" in s["reason"]
    assert any("30400920.05o" in w and "no raw GNSS log of the drone" in w for w in s["warnings"])
    assert json.loads((tmp_path / "out" / "ppk" / "summary.json").read_text())["skipped"] is True
    # a standard layout that names a rover folder still has to hold a log
    (survey / "rover").mkdir()
    with pytest.raises(InputFileError, match="no rover observation file"):
        run_survey_gnss(survey, tmp_path / "out2")


def test_a_raw_log_is_decoded_once_per_step(tmp_path, monkeypatch):
    """The band check (_has_second_frequency) and the solve read the same RTCM 3 raw log: decoded once."""
    from georef_core.gnss import rtcm3
    from georef_core.steps.gnss_solve import run_survey_gnss

    dji = _gsi_dji_survey(tmp_path / "dji", with_ephemerides=True, with_nav=False)
    decoded = []
    real = rtcm3.read_rtcm3

    def counting(path, *a, **k):
        decoded.append(Path(path).name)
        return real(path, *a, **k)

    monkeypatch.setattr(rtcm3, "read_rtcm3", counting)
    s = run_survey_gnss(dji, tmp_path / "out")
    assert s["events"]["count"] == 3 and s["options"]["n_bands"] == 2
    rover_reads = [n for n in decoded if n.endswith("PPKRAW.bin")]
    assert len(rover_reads) == 1, decoded


def test_loaded_observations_reused_only_inside_the_block(tmp_path):
    """reuse_loaded_observations: the same object inside the block, with the reader's warnings said to
    every caller (a truncated file stays named in the summary); a fresh decode outside it."""
    import warnings

    from georef_core.gnss.input_files import load_observations, reuse_loaded_observations

    data = (GSI / "07590920.05o").read_bytes()
    cut = tmp_path / "cut.obs"
    cut.write_bytes(data[: len(data) // 2])
    with reuse_loaded_observations():
        for _ in range(2):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                obj = load_observations(cut)
            assert any("truncated file" in str(w.message) for w in caught)
        assert load_observations(cut) is obj
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert load_observations(cut) is not obj
