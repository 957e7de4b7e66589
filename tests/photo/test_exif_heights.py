"""EXIF GPS heights that drift: detected against the block and the block levelled on the nadir-axis
assumption instead of tilted (photo/exif_heights.py). Known truth: the small simulated survey (session SfM
shared with test_sfm.py), its true camera centres given EXIF-like noise (the simulator's own 1.5 m / 3 m)
and an injected altitude drift of +60 m over the flight."""

from __future__ import annotations

import json
import math

import numpy as np

from georef_core.photo.align import fit_similarity
import pytest

from georef_core.photo.exif_heights import NADIR_SIGMA_DEG, OBLIQUE_AXIS_RMS_DEG, check_exif_heights
from georef_core.photo.photo_positions import EXIF_GPS_SIGMA_M
from georef_core.steps.georef import ImageGnss, image_flights


def _block(sim_sfm, photo_sim):
    poses = json.loads((photo_sim.truth_dir / "camera_poses.json").read_text())["images"]
    by_name = sim_sfm.reconstruction.image_by_name()
    rows = [p for p in poses if p["name"] in by_name]
    names = [p["name"] for p in rows]
    truth = np.array([p["camera_centre_enu_m"] for p in rows])
    t = np.array([p["exposure_gps_time_s"] for p in rows])
    C = np.array([by_name[n].centre for n in names])
    A = np.array([by_name[n].R_cam_from_world[2] for n in names])
    return truth, t, C, A


def _tilt_error_deg(C_sfm, enu_m, truth_enu_m) -> float:
    """The angle between the vertical a similarity onto ``enu_m`` gives the SfM block and the true one."""
    sim, _ = fit_similarity(C_sfm, enu_m)
    true, _ = fit_similarity(C_sfm, truth_enu_m)
    up = np.array([0.0, 0.0, 1.0])
    return math.degrees(math.acos(float(np.clip((sim.R.T @ up) @ (true.R.T @ up), -1, 1))))


def test_drifting_exif_heights_are_detected_and_the_block_levelled(sim_sfm, photo_sim):
    truth, t, C, A = _block(sim_sfm, photo_sim)
    assert len(truth) >= 10
    rng = np.random.default_rng(26)
    noise = rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    drift = 60.0 * (t - t.min()) / np.ptp(t)
    exif = truth + noise
    exif[:, 2] += drift

    before = _tilt_error_deg(C, exif, truth)
    out = check_exif_heights(C, A, exif, t, EXIF_GPS_SIGMA_M[1], sigma_h_m=1.0)
    assert out["inconsistent"] and "inconsistent with the block" in out["text"] and "nadir" in out["text"]
    # the drift it names is the injected one within its own 3 sigma plus the levelling's share
    assert abs(out["drift_m"] - 60.0) < 3 * out["drift_sigma_m"] + 10.0, out
    levelled = exif.copy()
    levelled[:, 2] = out["height_enu_m"]
    after = _tilt_error_deg(C, levelled, truth)
    print(f"tilt vs truth: heights as given {before:.1f} deg; levelled {after:.2f} deg "
          f"(stated sigma {out['level_sigma_deg']} deg); {out['text']}")
    assert before > 3 * NADIR_SIGMA_DEG           # the drift tilts a block fitted to the heights
    assert after < out["level_sigma_deg"]          # levelled within the stated sigma
    assert out["sigma_v_m"] >= EXIF_GPS_SIGMA_M[1]
    # the horizontal sigma raised from 1 m to the scatter about the levelled block: the drawn 1.5 m, roughly
    assert 1.0 < out["sigma_h_m"] < 3.0, out["sigma_h_m"]


def test_heights_without_drift_are_kept(sim_sfm, photo_sim):
    truth, t, C, A = _block(sim_sfm, photo_sim)
    rng = np.random.default_rng(27)
    exif = truth + rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    out = check_exif_heights(C, A, exif, t, EXIF_GPS_SIGMA_M[1])
    assert not out["inconsistent"] and "consistent" in out["text"] and "height_enu_m" not in out, out
    # without times there is nothing to test: said, not guessed
    out = check_exif_heights(C, A, exif, np.full(len(t), np.nan), EXIF_GPS_SIGMA_M[1])
    assert not out["inconsistent"] and "not checked" in out["text"]


def _rms(v) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


@pytest.mark.parametrize("drift_m, flight2_level_m", [((40.0, -30.0), 0.0), ((40.0, 0.0), 0.0), ((40.0, 0.0), 8.0)])
def test_drift_per_flight(sim_sfm, photo_sim, drift_m, flight2_level_m):
    """Two flights (a battery swap: the second line flown 300 s later), each barometer zeroed at its take-off and
    drifting on its own; optionally the second flight's zero 8 m higher (its take-off GPS altitude)."""
    truth, t, C, A = _block(sim_sfm, photo_sim)
    n = len(t)
    t = t + np.where(t > t.min() + 0.5 * np.ptp(t), 300.0, 0.0)
    gnss = ImageGnss([f"p{k}" for k in range(n)], t, np.zeros((n, 3)), np.zeros((n, 3)), np.ones((n, 3)),
                     np.ones(n, int), "simulated")
    by_name, how = image_flights(gnss, None, 120.0)          # the adjustment's flights: the same grouping
    flight = np.array([by_name[f"p{k}"] for k in range(n)])
    assert sorted(set(flight.tolist())) == [0, 1] and "gaps" in how
    rng = np.random.default_rng(26)
    exif = truth + rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    for f, dr in enumerate(drift_m):
        sel = flight == f
        exif[sel, 2] += dr * (t[sel] - t[sel].min()) / np.ptp(t[sel])
    exif[flight == 1, 2] += flight2_level_m

    before = _tilt_error_deg(C, exif, truth)
    out = check_exif_heights(C, A, exif, t, EXIF_GPS_SIGMA_M[1], sigma_h_m=1.0, flight=flight, level_at="start")
    assert out["inconsistent"] and out["levelled"] and out["n_flights"] == 2, out
    for row, dr in zip(out["flights"], drift_m):     # each flight's drift found, within 3 sigma + the levelling's share
        assert abs(row["drift_m"] - dr) < 3 * row["drift_sigma_m"] + 10.0, out["flights"]
    levelled = exif.copy()
    levelled[:, 2] = out["height_enu_m"]
    after = _tilt_error_deg(C, levelled, truth)
    # one level for the rigid block: the flights' levels averaged over the photos (the second 8 m high: half of it)
    common = flight2_level_m * float(np.mean(flight == 1))
    h_before = _rms(exif[:, 2] - truth[:, 2] - common)
    h_after = _rms(out["height_enu_m"] - truth[:, 2] - common)
    one = check_exif_heights(C, A, exif, t, EXIF_GPS_SIGMA_M[1], sigma_h_m=1.0)    # one drift for the survey
    print(f"drifts {drift_m} m, flight 2 level {flight2_level_m:+g} m: tilt {before:.1f} -> {after:.2f} deg (sigma "
          f"{out['level_sigma_deg']}); heights vs truth RMS {h_before:.1f} -> {h_after:.2f} m (+{common:g} m common); "
          f"found {[r['drift_m'] for r in out['flights']]} m, p = {out['p_value']}; one drift for the survey: "
          f"p = {one['p_value']}, levelled {one['levelled']}")
    assert before > 3 * NADIR_SIGMA_DEG
    assert after < out["level_sigma_deg"]
    assert h_after < EXIF_GPS_SIGMA_M[1] / 2 and h_after < h_before / 4


def _pitched(sim_sfm, photo_sim, pitch_deg: float):
    """The simulated block with every camera pitched ``pitch_deg`` towards the top of its image (forward on a
    serpentine: the two lines look opposite ways): the same centres, the optical axes (model frame) turned about
    each camera's x axis in the true level frame, and their true elevation and heading (DJI's gimbal pitch and yaw)."""
    truth, t, C, A = _block(sim_sfm, photo_sim)
    by_name = sim_sfm.reconstruction.image_by_name()
    poses = json.loads((photo_sim.truth_dir / "camera_poses.json").read_text())["images"]
    Rm = np.array([by_name[p["name"]].R_cam_from_world for p in poses if p["name"] in by_name])
    true_sim, _ = fit_similarity(C, truth)
    y_w, z_w = Rm[:, 1] @ true_sim.R.T, Rm[:, 2] @ true_sim.R.T
    a = math.radians(pitch_deg)
    z_ob = math.cos(a) * z_w - math.sin(a) * y_w
    pitch = np.degrees(np.arcsin(z_ob[:, 2]))
    yaw = np.degrees(np.arctan2(z_ob[:, 0], z_ob[:, 1]))
    return truth, t, C, z_ob @ true_sim.R, pitch, yaw


def test_oblique_block_levelled_on_recorded_attitudes_or_balanced_look_directions(sim_sfm, photo_sim):
    truth, t, C, A_ob, pitch, yaw = _pitched(sim_sfm, photo_sim, 30.0)
    assert np.all(np.abs(pitch + 60) < 8)            # 30 deg off nadir, give or take the body's attitude
    rng = np.random.default_rng(26)
    exif = truth + rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    exif[:, 2] += 60.0 * (t - t.min()) / np.ptp(t)
    before = _tilt_error_deg(C, exif, truth)
    # recorded: pitch to 0.3 deg, yaw 5 deg off (a compass offset) and 2 deg of scatter
    rec_pitch = pitch + rng.normal(0, 0.3, len(t))
    rec_yaw = yaw + 5.0 + rng.normal(0, 2.0, len(t))
    out = check_exif_heights(C, A_ob, exif, t, EXIF_GPS_SIGMA_M[1], gimbal_pitch_deg=rec_pitch, gimbal_yaw_deg=rec_yaw)
    assert out["inconsistent"] and out["levelled"] and out["level_method"] == "gimbal", out
    levelled = exif.copy()
    levelled[:, 2] = out["height_enu_m"]
    after = _tilt_error_deg(C, levelled, truth)
    # the nadir assumption on the same axes: what the levelling did before (their mean is near nadir, by symmetry)
    print(f"oblique 30 deg: tilt {before:.1f} -> {after:.2f} deg on the recorded attitudes (sigma "
          f"{out['level_sigma_deg']}, {out['gimbal']})")
    assert before > 3 * NADIR_SIGMA_DEG and after < out["level_sigma_deg"] <= NADIR_SIGMA_DEG

    # the same block without recorded attitudes: the axes' scatter says oblique; levelled on the stated assumption
    # that the look directions balance (forward on a serpentine: they do), and the warning says what it rests on
    out = check_exif_heights(C, A_ob, exif, t, EXIF_GPS_SIGMA_M[1])
    print(out["text"])
    assert out["axis_rms_deg"] > OBLIQUE_AXIS_RMS_DEG and out["levelled"] and out["level_method"] == "balanced-oblique"
    assert out["inconsistent"] and "oblique" in out["text"] and "mostly one way" in out["text"]
    levelled = exif.copy()
    levelled[:, 2] = out["height_enu_m"]
    tilt = _tilt_error_deg(C, levelled, truth)
    print(f"no recorded attitude: tilt {before:.1f} -> {tilt:.2f} deg (sigma {out['level_sigma_deg']})")
    assert tilt < out["level_sigma_deg"] < before / 4
    # the nadir block's own axes are well under the threshold (the same statistic)
    assert check_exif_heights(C, _block(sim_sfm, photo_sim)[3], exif, t, 5.0)["axis_rms_deg"] < OBLIQUE_AXIS_RMS_DEG

    # every camera looking the same way (north, 30 deg off nadir): the recorded attitudes leave the tilt about
    # north free (the block's yaw takes it), so they do not level it either
    true_sim, _ = fit_similarity(C, truth)
    e = np.array([0.0, math.sin(math.radians(30)), -math.cos(math.radians(30))]) + rng.normal(0, 0.01, (len(t), 3))
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    out = check_exif_heights(C, e @ true_sim.R, exif, t, 5.0, gimbal_pitch_deg=np.degrees(np.arcsin(e[:, 2])),
                             gimbal_yaw_deg=np.degrees(np.arctan2(e[:, 0], e[:, 1])))
    assert not out["levelled"] and "looking one way" in out["text"], out


def test_georef_step_levels_on_the_photos_gimbal_attitudes(sim_sfm, photo_sim):
    """The georef step's glue (steps/georef.py _exif_heights): the flights and the photos' recorded gimbal
    attitudes reach the check, the heights given to the adjustment are replaced only where the block is levelled,
    and a block that is not levelled is said in the warnings; heights from a barometer zeroed at take-off are placed
    at each flight's first photo."""
    from types import SimpleNamespace

    from georef_core.steps.georef import _exif_heights

    truth, t, C, A_ob, pitch, yaw = _pitched(sim_sfm, photo_sim, 30.0)
    by_name = sim_sfm.reconstruction.image_by_name()
    poses = json.loads((photo_sim.truth_dir / "camera_poses.json").read_text())["images"]
    names = [p["name"] for p in poses if p["name"] in by_name]
    images = {n: SimpleNamespace(centre=C[k], R_cam_from_world=np.vstack([np.zeros((2, 3)), A_ob[k]]))
              for k, n in enumerate(names)}
    rec = SimpleNamespace(image_by_name=lambda: images)
    rng = np.random.default_rng(26)
    exif = truth + rng.standard_normal(truth.shape) * np.array([1.5, 1.5, 3.0])
    exif[:, 2] += 60.0 * (t - t.min()) / np.ptp(t)
    n = len(names)
    one_way = np.column_stack([np.full(n := len(names), -60.0), np.zeros(n)])   # recorded: all looking north
    for case, gimbal in (("recorded", np.column_stack([pitch, yaw])), ("none", None), ("one way", one_way)):
        gnss = ImageGnss(names, t, np.zeros((n, 3)), np.zeros((n, 3)), np.ones((n, 3)), np.full(n, 5), "EXIF GPS",
                         from_photos=True, kind="exif-gps", gimbal_deg=gimbal, heights_from_takeoff=True)
        gnss_enu = {nm: (exif[k], np.zeros(3), np.diag([9.0, 9.0, 25.0]), 5, t[k]) for k, nm in enumerate(names)}
        warnings: list[str] = []
        out = _exif_heights(rec, gnss, gnss_enu, warnings, {nm: 0 for nm in names})
        z = np.array([gnss_enu[nm][0][2] for nm in names])
        assert out["inconsistent"] and len(warnings) == 1
        if case == "recorded":
            assert out["levelled"] and out["level_method"] == "gimbal" and "recorded gimbal attitudes" in warnings[0]
            # levelled heights given, at the level of the first photo (a barometer zeroed at take-off: DJI XMP)
            assert "first photo" in out["level_at"] and _rms(z - truth[:, 2]) < 5.0 < _rms(exif[:, 2] - truth[:, 2])
        elif case == "none":    # no attitude, axes scattered: levelled on balanced look directions, said
            assert out["levelled"] and out["level_method"] == "balanced-oblique" and "mostly one way" in warnings[0]
            assert _rms(z - truth[:, 2]) < 5.0 < _rms(exif[:, 2] - truth[:, 2])
        else:                   # recorded attitudes that leave the tilt free: not levelled, said, heights kept
            assert not out["levelled"] and "NOT levelled" in warnings[0]
            assert np.array_equal(z, exif[:, 2])                                      # kept as they were


def _with_dji_xmp(path, tags: dict) -> None:
    """Add a drone-dji XMP segment (APP1, right after the JPEG's start marker) with these attributes."""
    desc = " ".join(f'drone-dji:{k}="{v}"' for k, v in tags.items())
    packet = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
              f'<rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" {desc}/>'
              '</rdf:RDF></x:xmpmeta>').encode()
    seg = b"http://ns.adobe.com/xap/1.0/\x00" + packet
    raw = path.read_bytes()
    path.write_bytes(raw[:2] + b"\xff\xe1" + (len(seg) + 2).to_bytes(2, "big") + seg + raw[2:])


def test_photo_positions_carry_the_gimbal_attitude(photo_sim, tmp_path):
    """EXIF-GPS photos with DJI XMP (no RTK tags): their recorded gimbal pitch / yaw and whether their heights are
    a barometer's above take-off (RelativeAltitude) reach the georef step; photos without XMP: NaN, False."""
    import shutil

    from georef_core.photo.photo_positions import read_photo_positions

    names = sorted(p.name for p in (photo_sim.out_dir / "images").glob("*.JPG"))[:3]
    for nm in names:
        shutil.copy(photo_sim.out_dir / "images" / nm, tmp_path / nm)
    pp = read_photo_positions(tmp_path, names)
    assert pp.kind == "exif-gps" and np.all(np.isnan(pp.gimbal_deg)) and not pp.heights_from_takeoff
    for k, nm in enumerate(names):
        _with_dji_xmp(tmp_path / nm, {"GimbalPitchDegree": f"{-60.0 - k:+.2f}", "GimbalYawDegree": "+91.50",
                                      "RelativeAltitude": "+40.000"})
    pp = read_photo_positions(tmp_path, names)
    assert pp.kind == "exif-gps" and pp.heights_from_takeoff
    assert np.allclose(pp.gimbal_deg, [[-60.0, 91.5], [-61.0, 91.5], [-62.0, 91.5]])
