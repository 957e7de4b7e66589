"""Step: PPK baseline processing. Reads the rover, base and navigation files, writes the solution as
RTKLIB .pos + Parquet (+ residuals), the antenna positions at camera events (CSV) and a JSON summary.
The CLI (`georef gnss solve`) and the worker call this same function."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ProcessingError
from ..gnss.camera_events import interpolate_at_events, read_event_csv, write_event_csv
from ..gnss.ppk import solve_files
from ..gnss.rtk_options import RtkOptions
from ..gnss.solution_io import write_parquet, write_pos


def run_gnss_solve(rover_path, base_path, nav_paths, out_pos, opts: RtkOptions, events_csv=None,
                   epsg: int | None = None, parquet_path=None, events_out=None,
                   rover_events_first: bool = False, approx_gps_time_s: float | None = None,
                   progress=None) -> dict:
    """Solve and write the outputs. Camera events come from ``events_csv`` when given; with
    ``rover_events_first`` the rover file's own event records win and the CSV is only the fallback.
    ``progress(stage, done, total)`` as ppk.solve_files reports it."""
    out_pos = Path(out_pos)
    out_pos.parent.mkdir(parents=True, exist_ok=True)
    sol = solve_files(rover_path, base_path, nav_paths, opts, approx_gps_time_s, progress=progress)
    write_pos(out_pos, sol)
    parquet_path = Path(parquet_path) if parquet_path else out_pos.with_suffix(".parquet")
    write_parquet(parquet_path, sol, epsg)
    events = np.asarray(sol.event_time_s, dtype=float)
    rover_names = ", ".join(Path(p).name for p in ([rover_path] if isinstance(rover_path, (str, Path)) else rover_path))
    events_source = f"event records in {rover_names}" if len(events) else None
    if events_csv and not (rover_events_first and len(events)):
        events = read_event_csv(events_csv)
        events_source = str(events_csv)
    summary = {
        "epochs": int(len(sol.time_s)),
        "fix": int(np.sum(sol.status == 1)), "float": int(np.sum(sol.status == 2)), "single": int(np.sum(sol.status == 5)),
        "fix_rate": round(sol.fix_rate, 4),
        # epochs both filter directions fixed more than 5 cm apart (fix_witness.py): not output as fixed
        # unless the carrier phase decided between them
        "fix_conflicts": int(np.sum(sol.fix_conflicts)) if sol.fix_conflicts is not None else 0,
        "base_position_ecef_m": [round(float(v), 4) for v in sol.base_position_ecef_m],
        # where it came from and how uncertain: every position of the solution shares its error
        "base_position": dict(sol.base_position_basis),
        # receiver and antenna models as the rover's and base's files state them (gnss/receiver_equipment.py)
        "equipment": dict(sol.equipment),
        "outputs": {"pos": str(out_pos), "parquet": str(parquet_path)},
        "timings_s": {k: round(v, 3) for k, v in sol.timings_s.items()},
        "warnings": sol.warnings,
    }
    # when the drone flew (GPS seconds): its camera triggers, else the solution (the survey's flight time)
    from .flight_time import gnss_time_span

    summary["time_span"] = gnss_time_span(sol.time_s, events)
    if len(events):
        ev = interpolate_at_events(sol, events)
        events_out = Path(events_out) if events_out else out_pos.with_name(out_pos.stem + "_events.csv")
        write_event_csv(events_out, ev, epsg)
        summary["events"] = {"count": int(len(events)), "fixed": int(np.sum(ev.status == 1)),
                             "without_solution": int(np.sum(ev.status == 0)), "csv": str(events_out),
                             "source": events_source}
    summary_path = out_pos.with_name(out_pos.stem + "_summary.json")
    summary_path.write_text(json.dumps(summary, indent=2))
    summary["outputs"]["summary"] = str(summary_path)
    return summary


# --------------------------------------------------------------------------------------------------------
# the survey-folder form used by `georef georef` and the worker
# --------------------------------------------------------------------------------------------------------

def _has_second_frequency(path: Path, approx_gps_time_s: float | None = None) -> bool:
    """Whether the receiver tracked phase on a second band (L2/L5/E5b/B2...): from a RINEX observation
    header's list, or from the decoded signals of a UBX log or RTCM 3 stream (an F9P or a DJI aircraft
    records two bands, an M8T one)."""
    from ..gnss.compressed_files import read_bytes
    from ..gnss.input_files import load_observations, sniff_kind

    kind = sniff_kind(path)
    if kind in ("ubx", "rtcm3"):
        from ..gnss.constants import RINEX_DIGIT_TO_BAND

        raw = load_observations(path, approx_gps_time_s).observations
        tracked = ~np.all(np.isnan(raw.values), axis=0)          # (S, K)
        return any(c[0] == "L" and RINEX_DIGIT_TO_BAND.get(sat[0], {}).get(c[1], 0) >= 1 and tracked[s, k]
                   for k, c in enumerate(raw.obs_codes) for s, sat in enumerate(raw.sat_ids))
    if kind != "rinex-obs":
        return False
    head = read_bytes(path)[:200000].decode("latin-1", errors="replace")
    end = head.find("END OF HEADER")
    head = head[:end if end > 0 else len(head)]
    for line in head.splitlines():
        label = line[60:].strip()
        if label in ("SYS / # / OBS TYPES", "# / TYPES OF OBSERV"):
            for tok in line[:60].split():
                if tok[:2] in ("L2", "L5", "L7", "L6", "L8"):
                    return True
    return False


def read_survey_json(survey_dir) -> dict:
    """``survey.json`` of a survey folder (what the surveyor knows besides the files), or {}."""
    p = Path(survey_dir) / "survey.json"
    if not p.is_file():
        return {}
    try:
        doc = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise InputFileError(p, f"not valid JSON ({exc})") from None
    except RecursionError:
        raise InputFileError(p, "JSON nested too deeply (not a survey description)") from None
    except UnicodeDecodeError as exc:
        raise InputFileError(p, f"not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    if not isinstance(doc, dict):
        raise InputFileError(p, f"expected a JSON object (names and values), found a JSON {type(doc).__name__}")
    return doc


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The gnss step as the contract runs it (specs.GNSS): coordinates also in the site's CRS."""
    options = dict(options or {})
    crs = str(context.get("crs") or "")
    if options.get("epsg") is None and crs.upper().startswith("EPSG:"):
        options["epsg"] = int(crs.split(":")[1])
    return run_survey_gnss(workspace.survey_dir, workspace.out_dir, options, progress)


def run_survey_gnss(survey_dir, out_dir, options: dict | None = None, progress=None, found=None) -> dict:
    """PPK for a survey folder (rover/, base/, nav/, optional events.csv and survey.json, or DJI flight
    folders beside base/: survey_inputs.py; ``found``: its result when the caller already has it) into
    ``out_dir/ppk/``. A survey of photos alone (no raw log, no base) has nothing to solve: the summary
    says ``skipped`` and why. Options: ``freq`` ('auto', 'l1', 'l1+l2'), ``mode`` ('auto', 'kinematic',
    'known-start'), ``direction`` ('combined', 'forward', 'backward'), ``base_position_ecef_m``,
    ``known_start_ecef_m``, ``epsg``, ``events_csv`` (trigger times that override the survey's), and the CLI's ``elmask`` (deg), ``ar`` (ambiguity mode), ``ratio``
    (ratio-test threshold), ``navsys`` ('G,E,...'), ``tdcp_slips`` (m), ``hold_variance`` (cycles²); the summary
    records the engine options used. 'auto' picks dual frequency when the rover records a second band,
    and single-frequency known-start when it does not and survey.json gives the take-off point."""
    from ..gnss.input_files import reuse_loaded_observations

    with reuse_loaded_observations():     # the band check and the solve decode a raw log once
        return _run_survey_gnss(survey_dir, out_dir, options, progress, found)


def _run_survey_gnss(survey_dir, out_dir, options: dict | None, progress, found) -> dict:
    survey_dir = Path(survey_dir)
    out = Path(out_dir) / "ppk"
    from .contract import get_spec

    opt = {k: v for k, v in get_spec("gnss").validate(dict(options or {})).items() if v is not None}
    meta = read_survey_json(survey_dir)
    from .survey_inputs import survey_inputs

    found = found if found is not None else survey_inputs(survey_dir, out_dir)   # georef passes its own
    rovers, bases, navs = found.rover_files, found.base_files, found.nav_files
    if not rovers and not (survey_dir / "rover").is_dir():
        # photos alone (RTK-tagged or EXIF GPS): nothing to solve; the georef step uses their positions (the
        # platform's GNSS step sees the observation files only, not the photos: no photos is no reason to fail).
        # A base without the drone's raw log (a DJI flight folder with photos and MRK but no *_PPKRAW.bin) is
        # the same: PPK needs both receivers; said in a warning, not an error (the photos still carry positions)
        out.mkdir(parents=True, exist_ok=True)
        warnings = list(found.warnings)
        if bases:
            warnings.append(f"base observations given ({', '.join(Path(b).name for b in bases)}) but no raw GNSS log "
                            f"of the drone (e.g. DJI *_PPKRAW.bin or *_Rinex.obs beside the photos): PPK needs "
                            f"both, so the photos' own positions (RTK XMP or EXIF GPS) georeference the survey")
        reason = ("no raw GNSS log of the drone" + (" (a base alone cannot be solved)" if bases else " and no base")
                  + ": the photos' own positions (RTK XMP or EXIF GPS) georeference the survey")
        summary = {"skipped": True, "reason": reason, "inputs": found.summary(), "warnings": warnings}
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        if progress:
            progress("gnss", 1, 1)
        return summary
    if not rovers:
        where = "the DJI flight folders" if found.layout == "dji" else str(survey_dir / "rover")
        raise InputFileError(survey_dir / "rover" if found.layout != "dji" else found.flights[0].folder,
                             f"no rover observation file (RINEX obs, u-blox UBX or RTCM 3 raw log) found in {where}")
    if not bases:
        raise InputFileError(survey_dir / "base", "no base-station observation file (RINEX obs, UBX or RTCM 3) found here")
    if progress:
        progress("gnss", 0, 1)
    freq = opt.get("freq", "auto")
    bands = {"l1": 1, "l1+l2": 2, "l1+l2+l5": 3}
    if freq != "auto" and freq not in bands:
        raise ProcessingError(f"GNSS settings: freq {freq!r} is not one of auto, {', '.join(bands)}")
    approx_t = _first_event_time(found.events_csv) if found.layout == "dji" else None
    n_bands = bands[freq] if freq != "auto" else (2 if _has_second_frequency(rovers[0], approx_t) else 1)
    mode = opt.get("mode", "auto")
    known = opt.get("known_start_ecef_m") or meta.get("takeoff_antenna_ecef_m")
    if mode == "auto":
        mode = "known-start" if (n_bands == 1 and known is not None) else "kinematic"
    kw = dict(mode=mode, n_bands=n_bands, filter_direction=opt.get("direction", opt.get("filter", "combined")))
    for key, field, cast in (("elmask", "elevation_mask_deg", float), ("ar", "ar_mode", str),
                             ("ratio", "ratio_threshold", float), ("tdcp_slips", "slip_tdcp_threshold_m", float),
                             ("hold_variance", "hold_variance_cyc2", float),
                             ("fix_max_sigma", "fix_max_sigma_m", float)):
        if opt.get(key) is not None:      # types checked by the spec (get_spec("gnss").validate above)
            kw[field] = cast(opt[key])
    if opt.get("reverse_witness") is not None:
        kw["reverse_witness"] = opt["reverse_witness"]
    if opt.get("event_edge") is not None:
        kw["ubx_event_edge"] = opt["event_edge"]
    if opt.get("navsys"):
        kw["systems"] = tuple(s.strip().upper() for s in str(opt["navsys"]).split(",") if s.strip())
    if mode == "known-start":
        if known is None:
            raise InputFileError(survey_dir / "survey.json", "known-start mode needs the take-off antenna position "
                                                             "(takeoff_antenna_ecef_m)")
        kw["known_start_position_ecef_m"] = tuple(float(v) for v in known)
    if opt.get("base_position_ecef_m") is not None:
        kw["base_position_ecef_m"] = tuple(float(v) for v in opt["base_position_ecef_m"])
    rtk = RtkOptions(**kw)
    try:
        rtk.validate()
    except ValueError as exc:
        raise ProcessingError(f"GNSS settings: {exc}") from None
    events_csv = found.events_csv
    rover_events_first = found.layout != "dji"     # a DJI MRK's exposures win over any event records
    exif_warnings: list[str] = []
    if opt.get("exif_time_offset_s") is not None:
        # the photos' EXIF times plus the camera-clock offset are the triggers (exif_triggers.py)
        from .exif_triggers import exif_trigger_times, write_trigger_csv
        from .georef_options import IMAGE_SUFFIXES

        image_dir = found.image_dir
        names = sorted(p.name for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES) \
            if image_dir is not None and image_dir.is_dir() else []
        if not names:
            raise InputFileError(survey_dir / "images", "exif_time_offset_s is set but the survey has no photos to "
                                                        "take trigger times from")
        times, exif_warnings = exif_trigger_times(image_dir, names, float(opt["exif_time_offset_s"]))
        write_trigger_csv(out / "exif_triggers.csv", times)
        events_csv, rover_events_first = out / "exif_triggers.csv", False
    if opt.get("events_csv"):  # trigger times given explicitly: they win
        events_csv, rover_events_first = Path(opt["events_csv"]), False
    epsg = opt.get("epsg")
    if epsg is None and meta.get("project_crs", "").upper().startswith("EPSG:"):
        epsg = int(meta["project_crs"].split(":")[1])
    summary = run_gnss_solve(rovers if len(rovers) > 1 else rovers[0], bases if len(bases) > 1 else bases[0], navs,
                             out / "trajectory.pos", rtk, events_csv=events_csv, epsg=epsg,
                             events_out=out / "events.csv", rover_events_first=rover_events_first,
                             approx_gps_time_s=approx_t, progress=_solve_progress(progress))
    summary["warnings"] = found.warnings + exif_warnings + summary.get("warnings", [])
    rover_eq = (summary.get("equipment") or {}).get("rover")
    if found.layout == "dji" and rover_eq:
        from ..gnss.receiver_equipment import FORMAT_LABELS

        if rover_eq.get("format") == FORMAT_LABELS["rtcm3"]:
            rover_eq["format"] = FORMAT_LABELS["dji-rtcm3"]      # the aircraft's *_PPKRAW.bin
    summary["triggers_sha256"] = trigger_table_key(events_csv)   # the georef command's PPK reuse keys
    summary["inputs_sha256"] = gnss_inputs_key(found, options)
    if opt.get("exif_time_offset_s") is not None:
        summary["exif_time_offset_s"] = float(opt["exif_time_offset_s"])
    # paths relative to the run folder, so a moved or re-used run folder stays valid
    summary["outputs"] = {k: _relative_to(v, out_dir) for k, v in summary["outputs"].items()}
    if "events" in summary:
        summary["events"]["csv"] = _relative_to(summary["events"]["csv"], out_dir)
        if summary["events"]["source"] and Path(summary["events"]["source"]).is_absolute():
            summary["events"]["source"] = _relative_to(summary["events"]["source"], survey_dir)
    summary["inputs"] = {"rover": [_relative_to(p, survey_dir) for p in rovers],
                         "base": [_relative_to(p, survey_dir) for p in bases],
                         "nav": [_relative_to(p, survey_dir) for p in navs], "layout": found.layout}
    if found.flights:
        summary["inputs"]["flights"] = found.summary()["flights"]
    summary["options"] = {"mode": mode, "n_bands": n_bands, "direction": kw["filter_direction"], "ar": rtk.ar_mode,
                          "ratio": rtk.ratio_threshold, "elmask_deg": rtk.elevation_mask_deg,
                          "systems": list(rtk.systems), "tdcp_slips_m": rtk.slip_tdcp_threshold_m,
                          "hold_variance_cyc2": rtk.hold_variance_cyc2}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    if progress:
        progress("gnss", 1, 1)
    return summary


def _solve_progress(progress):
    """The solve's stages as the step's progress ("gnss: Kalman filter, forward pass", 2 / 4), saying when the
    kernels are compiled first (not in numba's cache: a fresh install without `georef warmup`)."""
    if not progress:
        return None
    from ..warmup import GNSS_COMPILE_ESTIMATE_S, gnss_kernels_cached

    note = "" if gnss_kernels_cached() else f" (first run: compiling the kernels, about {GNSS_COMPILE_ESTIMATE_S} s)"
    return lambda stage, done, total: progress(f"gnss: {stage}{note}", done, total)


def trigger_times_key(times) -> str:
    """sha256 of trigger times (GPS s, to the microsecond, in time order): what a PPK's camera events depend
    on besides the observations. The GNSS step records it in ppk/summary.json (triggers_sha256); the georef
    command reuses an earlier PPK only under the same key, so a changed trigger time runs the PPK again."""
    import hashlib

    t = np.sort(np.asarray(list(times), float))
    return hashlib.sha256("\n".join(f"{v:.6f}" for v in t).encode()).hexdigest()


def gnss_inputs_key(found, options: dict | None) -> str:
    """sha256 of what a PPK depends on besides its trigger times (:func:`trigger_table_key`): the content of
    every GNSS file of the survey (rover, base and navigation files, DJI MRK files, the trigger and camera
    offset tables, survey.json with its take-off point) and the GNSS options after validation (defaults
    filled). The GNSS step records it in ppk/summary.json (inputs_sha256); the georef command reuses an earlier
    PPK only under the same key, so a replaced, added or edited observation file or a changed option runs the
    PPK again (as the SfM is keyed on the photos: photo/sfm.sfm_inputs_key)."""
    import hashlib

    from .contract import get_spec

    survey_dir = Path(found.survey_dir)
    files = [*found.rover_files, *found.base_files, *found.nav_files, *(f.mrk_path for f in found.flights),
             found.events_csv, found.camera_offsets_csv, survey_dir / "survey.json"]
    h = hashlib.sha256()
    for path in sorted({Path(p) for p in files if p is not None and Path(p).is_file()}):
        digest = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        h.update(f"{_relative_to(path, survey_dir)}\0{digest.hexdigest()}\n".encode())
    spec = get_spec("gnss")
    opt = {o.name: o.default for o in spec.options if o.default is not None}    # a default written out or not
    opt.update({k: v for k, v in spec.validate(dict(options or {})).items() if v is not None})
    h.update(json.dumps(opt, sort_keys=True, default=str).encode())
    return h.hexdigest()


def trigger_table_key(events_csv) -> str | None:
    """:func:`trigger_times_key` of a trigger table (events.csv, a DJI MRK's, an EXIF-times table); None
    without one (the triggers are then the rover log's own event records)."""
    if not events_csv or not Path(events_csv).is_file():
        return None
    try:
        return trigger_times_key(read_event_csv(events_csv))
    except InputFileError:      # not a table the solve reads (the rover's records win): its bytes, then
        import hashlib

        return "file:" + hashlib.sha256(Path(events_csv).read_bytes()).hexdigest()


def _first_event_time(events_csv) -> float | None:
    """The earliest trigger time of a trigger table (dates a raw log that carries no week number)."""
    from ..gnss.camera_events import read_event_csv

    times = read_event_csv(events_csv) if events_csv else []
    return float(min(times)) if len(times) else None


def _relative_to(path, root) -> str:
    try:
        return Path(path).resolve().relative_to(Path(root).resolve()).as_posix()
    except ValueError:
        return str(path)
