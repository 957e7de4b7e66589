"""The pre-flight check of a survey folder: what is there, and what would stop or weaken processing,
from the metadata read when each file was uploaded (file_kinds) and, for DJI flights, the (small)
Timestamp.MRK files themselves. Each problem has a code the UI keys on; ``summary`` names what was
found in one line ("2 flights, 419 photos, MRK 419 exposures, RTCM 3 rover log, base: 3 RINEX files, no
navigation file needed").

The folder is read as the pipeline reads it (georef_core.steps.survey_inputs): the standard layout
(rover/, base/, nav/, images/, events.csv) or DJI flight folders (flights/<name>/ with a Timestamp.MRK,
its photos and the aircraft's raw log) plus base/, nav/, gcp/. Several rover files (flights after
battery swaps) and several base files (hourly CORS files, a log split by restarts) are joined in time
order: the check names them, their time span and the gaps between them."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import datetime, timedelta

from ..models import SurveyFile
from ..storage import blob_key
from . import file_kinds

OBS_KINDS = file_kinds.OBSERVATION_KINDS
FLIGHTS = "flights/"
GPS_EPOCH = datetime(1980, 1, 6)
MIN_EPHEMERIS_SATELLITES = 4          # per system: fewer and most of its satellites cannot be used
MRK_READ_MAX_BYTES = 20 * 1024**2
# photo number at the end of a DJI photo name (DJI_0042.JPG, DJI_20241126120000_0042_V.JPG), as
# georef_core.steps.survey_inputs ties photos to exposures
_PHOTO_NUMBER = re.compile(r"(\d+)(?:_[A-Za-z]{1,3})?\.(?:jpe?g|tiff?|png)$", re.IGNORECASE)
_KIND_WORDS = {"rinex-obs": ("RINEX file", "RINEX files"), "ubx": ("UBX log", "UBX logs"),
               "rtcm3": ("RTCM 3 log", "RTCM 3 logs")}


def _problem(severity: str, code: str, message: str, files=()) -> dict:
    return {"severity": severity, "code": code, "message": message, "files": list(files)}


def _name(f: SurveyFile) -> str:
    return f.path.rsplit("/", 1)[-1]


def gps_datetime(t: float) -> datetime:
    return GPS_EPOCH + timedelta(seconds=float(t))


def fmt_time(t: float) -> str:
    return gps_datetime(t).strftime("%Y-%m-%d %H:%M")


def fmt_span(a: float, b: float) -> str:
    da, db = gps_datetime(a), gps_datetime(b)
    if da.date() == db.date():
        return f"{da:%Y-%m-%d %H:%M}-{db:%H:%M}"
    return f"{da:%Y-%m-%d %H:%M} - {db:%Y-%m-%d %H:%M}"


def fmt_duration(s: float) -> str:
    s = abs(s)
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def _plural(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else (many or one + 's')}"


# ----------------------------------------------------------------------------------------------- times


def file_span(f: SurveyFile, ref_gps_s: float | None = None) -> tuple[float, float] | None:
    """(first, last) GPS time of an observation file's epochs; an RTCM 3 log that carries no week (no
    ephemeris) is dated near ``ref_gps_s`` (e.g. its flight's MRK, which writes the full week)."""
    m = f.meta or {}
    a, b = m.get("first_gps_time_s"), m.get("last_gps_time_s")
    if a is not None and b is not None:
        return float(a), float(b)
    if ref_gps_s is not None and m.get("first_tow_s") is not None and m.get("last_tow_s") is not None:
        from georef_core.gnss.gnss_time import resolve_tow_near

        t0 = resolve_tow_near(float(m["first_tow_s"]), float(ref_gps_s))
        return t0, t0 + float(m["last_tow_s"]) - float(m["first_tow_s"])
    return None


def _interval_s(f: SurveyFile, span: tuple[float, float]) -> float:
    m = f.meta or {}
    if m.get("interval_s"):
        return float(m["interval_s"])
    n = m.get("epochs") or m.get("rawx_epochs")
    if n and int(n) > 1:
        return (span[1] - span[0]) / (int(n) - 1)
    return 1.0


def _merge(spans: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[list[float]] = []
    for a, b in sorted(spans):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def _covered(target: tuple[float, float], spans: list[tuple[float, float]]) -> float:
    return sum(max(0.0, min(b, target[1]) - max(a, target[0])) for a, b in _merge(spans))


@dataclass
class Joined:
    """Several files of one receiver in time order: the message that names them and their gaps."""

    message: str
    gaps: list[tuple[str, str, float, float]] = field(default_factory=list)   # (before, after, start, end)
    overlaps: list[tuple[str, str, float]] = field(default_factory=list)
    duplicates: list[tuple[str, str]] = field(default_factory=list)
    unknown: list[str] = field(default_factory=list)                          # files without a time span
    span: tuple[float, float] | None = None


def join_report(label: str, files: list[SurveyFile], span_of) -> Joined:
    """Several files of one receiver in time order, e.g. "base: 3 RINEX files, 2018-10-24 04:00-07:00, gap
    of 600 s between a and b"; ``span_of(file)`` gives each file's (first, last) GPS time or None."""
    out = Joined("")
    seen: dict[str, str] = {}
    timed = []
    for f in files:
        if f.sha256 in seen:
            out.duplicates.append((seen[f.sha256], f.path))
        seen.setdefault(f.sha256, f.path)
        sp = span_of(f)
        if sp is None:
            out.unknown.append(f.path)
        else:
            timed.append((sp, f))
    timed.sort(key=lambda x: x[0][0])
    parts = [f"{label}: {_count_phrase(files)}"]
    if timed:
        out.span = (min(sp[0] for sp, _ in timed), max(sp[1] for sp, _ in timed))
        parts.append(fmt_span(*out.span))
        (end_span, end_f) = timed[0]
        for sp, f in timed[1:]:
            gap = sp[0] - end_span[1]
            tol = 1.5 * max(_interval_s(end_f, end_span), _interval_s(f, sp)) + 0.5
            if gap > tol:
                out.gaps.append((_name(end_f), _name(f), end_span[1], sp[0]))
                parts.append(f"gap of {gap:.0f} s between {_name(end_f)} and {_name(f)}")
            elif gap < 0 and end_f.sha256 != f.sha256:
                out.overlaps.append((end_f.path, f.path, min(-gap, sp[1] - sp[0])))
            if sp[1] > end_span[1]:
                end_span, end_f = sp, f
        if len(timed) > 1 and not out.gaps:
            parts.append("no gap")
    if out.unknown:
        parts.append(f"time span of {', '.join(p.rsplit('/', 1)[-1] for p in out.unknown[:5])} not known before "
                     "processing")
    out.message = ", ".join(parts)
    return out


def _count_phrase(files: list[SurveyFile]) -> str:
    """'3 RINEX files', '1 RTCM 3 log', '2 files (RINEX, RTCM 3)'."""
    kinds = sorted({f.kind for f in files})
    if len(kinds) == 1:
        return _plural(len(files), *_KIND_WORDS.get(kinds[0], ("file", "files")))
    return f"{len(files)} files ({', '.join(_KIND_WORDS.get(k, (k,))[0].rsplit(' ', 1)[0] for k in kinds)})"


_ROVER_WORDS = {"rtcm3": ("RTCM 3 rover log", "RTCM 3 rover logs"), "rinex-obs": ("RINEX rover file", "RINEX rover files"),
                "ubx": ("UBX rover log", "UBX rover logs")}


def _rover_phrase(files: list[SurveyFile]) -> str:
    """'RTCM 3 rover log', '2 RTCM 3 rover logs', '2 rover files (RINEX, RTCM 3)'."""
    kinds = sorted({f.kind for f in files})
    if len(kinds) == 1 and kinds[0] in _ROVER_WORDS:
        one, many = _ROVER_WORDS[kinds[0]]
        return one if len(files) == 1 else f"{len(files)} {many}"
    return f"{len(files)} rover files ({', '.join(_KIND_WORDS.get(k, (k,))[0].rsplit(' ', 1)[0] for k in kinds)})"


# ----------------------------------------------------------------------------------------------- DJI


@dataclass
class Flight:
    name: str
    mrks: list[SurveyFile] = field(default_factory=list)
    photos: list[SurveyFile] = field(default_factory=list)
    logs: list[SurveyFile] = field(default_factory=list)
    navs: list[SurveyFile] = field(default_factory=list)

    @property
    def folder(self) -> str:
        return f"{FLIGHTS}{self.name}"

    @property
    def exposures(self) -> int:
        return sum(int((m.meta or {}).get("exposures", 0)) for m in self.mrks)

    def mrk_span(self) -> tuple[float, float] | None:
        m = (self.mrks[0].meta or {}) if self.mrks else {}
        if m.get("first_gps_time_s") is None:
            return None
        return float(m["first_gps_time_s"]), float(m["last_gps_time_s"])


def _read_mrk(ctx, f: SurveyFile):
    """The MRK's exposures (index, GPS time), or None when it cannot be read here."""
    if f.size > MRK_READ_MAX_BYTES:
        return None
    try:
        from georef_core.gnss.dji_mrk import parse_mrk_text

        data = ctx.storage.read_bytes(blob_key(f.sha256))
        if data[:2] == b"\x1f\x8b":
            import gzip

            data = gzip.decompress(data)
        return parse_mrk_text(data.decode("utf-8-sig", errors="replace"), f.path)
    except Exception:    # noqa: BLE001  (checked at upload; a read problem here only skips the detail)
        return None


def _photo_numbers(photos: list[SurveyFile]) -> list[int] | None:
    nums = []
    for p in photos:
        m = _PHOTO_NUMBER.search(_name(p))
        if m is None:
            return None
        nums.append(int(m.group(1)))
    return nums if len(set(nums)) == len(nums) else None


def _exif_spread_s(photos: list[SurveyFile], gps_times: list[float]) -> float | None:
    """Spread of (EXIF time - MRK time) over a flight, folded into one quarter hour (time zones), as
    georef_core.steps.survey_inputs computes it; None with fewer than two EXIF times."""
    diffs = []
    for p, t in zip(photos, gps_times):
        text = (p.meta or {}).get("time_original")
        if not text:
            continue
        try:
            exif = datetime.fromisoformat(text)
        except ValueError:
            continue
        diffs.append((exif - gps_datetime(t)).total_seconds())
    if len(diffs) < 2:
        return None
    d0 = diffs[0]
    folded = [d - 900.0 * round((d - d0) / 900.0) for d in diffs]
    return max(folded) - min(folded)


def _camera(p: SurveyFile) -> str | None:
    m = p.meta or {}
    if not (m.get("make") or m.get("model")):
        return None
    return f"{m.get('make') or '?'} {m.get('model') or '?'} {m.get('width', '?')}x{m.get('height', '?')}"


def check_flight(ctx, fl: Flight, problems: list[dict]) -> str | None:
    """The checks of one DJI flight folder; returns its camera (make model size) when known."""
    from georef_core.steps.survey_inputs import MAX_EXIF_MRK_SPREAD_S

    if len(fl.mrks) > 1:
        problems.append(_problem("error", "several-mrk-files",
                                 f"{fl.folder} holds {len(fl.mrks)} Timestamp.MRK files "
                                 f"({', '.join(_name(m) for m in fl.mrks)}): keep each flight in its own folder",
                                 [m.path for m in fl.mrks]))
        return None
    mrk_f = fl.mrks[0]
    n_exp, n_photo = fl.exposures, len(fl.photos)
    if n_photo == 0:
        problems.append(_problem("error", "mrk-photo-mismatch",
                                 f"{mrk_f.path} lists {n_exp} exposures but {fl.folder} holds no photo: upload the "
                                 "flight's photos into the same folder", [mrk_f.path]))
        return None
    mrk = _read_mrk(ctx, mrk_f)
    nums = _photo_numbers(fl.photos)
    rows = None
    how = ""
    if mrk is not None:
        row_of = {int(k): i for i, k in enumerate(mrk.index.tolist())}
        if nums is not None and all(k in row_of for k in nums):
            rows, how = [row_of[k] for k in nums], "photo numbers"
        elif n_photo == n_exp:
            rows, how = list(range(n_photo)), "order"
        else:
            unknown = [_name(p) for p, k in zip(fl.photos, nums or []) if k not in row_of][:5]
            detail = f" (no exposure for {', '.join(unknown)})" if unknown else ""
            problems.append(_problem("error", "mrk-photo-mismatch",
                                     f"{_name(mrk_f)}: {n_exp} exposures but {n_photo} photos in {fl.folder}{detail}: "
                                     "the MRK does not belong to these photos",
                                     [mrk_f.path] + [f"{fl.folder}/{n}" for n in unknown]))
    elif n_photo > n_exp:
        problems.append(_problem("error", "mrk-photo-mismatch",
                                 f"{_name(mrk_f)}: {n_exp} exposures but {n_photo} photos in {fl.folder}: the MRK does "
                                 "not belong to these photos", [mrk_f.path]))
    if (rows is not None or mrk is None) and n_exp > n_photo:
        problems.append(_problem("warning", "exposures-without-photos",
                                 f"{_name(mrk_f)}: {n_exp - n_photo} of {n_exp} exposures have no photo in {fl.folder} "
                                 "(deleted photos, or photos not uploaded?)", [mrk_f.path]))
    if rows is not None:
        order = sorted(range(n_photo), key=lambda i: _name(fl.photos[i]))
        spread = _exif_spread_s([fl.photos[i] for i in order], [float(mrk.gps_time_s[rows[i]]) for i in order])
        if spread is not None and spread > MAX_EXIF_MRK_SPREAD_S:
            problems.append(_problem("error", "mrk-photo-time-mismatch",
                                     f"{_name(mrk_f)}: the photos' EXIF times in {fl.folder} do not follow the MRK's "
                                     f"exposure times (matched by {how}, their difference varies by {spread:.1f} s, "
                                     f"more than {MAX_EXIF_MRK_SPREAD_S:g} s): the MRK does not belong to these "
                                     "photos, or photos were renamed", [mrk_f.path]))
    cams: dict[str, list[str]] = {}
    for p in sorted(fl.photos, key=lambda p: p.path):
        c = _camera(p)
        if c is not None:
            cams.setdefault(c, []).append(p.path)
    if len(cams) > 1:
        parts = "; ".join(f"{c}: {len(ps)} ({', '.join(x.rsplit('/', 1)[-1] for x in ps[:2])}"
                          f"{' ...' if len(ps) > 2 else ''})" for c, ps in cams.items())
        problems.append(_problem("error", "mixed-cameras",
                                 f"photos of more than one camera in {fl.folder} ({parts}): photos from two aircraft "
                                 "are mixed; keep one aircraft's flight per folder",
                                 [p for ps in cams.values() for p in ps[:3]]))
        return None
    return next(iter(cams), None)


# ----------------------------------------------------------------------------------------------- check


def run(ctx, s, files: list[SurveyFile], site) -> dict:
    problems: list[dict] = []
    by_kind: dict[str, list[SurveyFile]] = {}
    flights: dict[str, Flight] = {}
    for f in files:
        by_kind.setdefault(f.kind, []).append(f)
        if f.path.startswith(FLIGHTS) and f.path.count("/") >= 2:
            name = f.path.split("/")[1]
            fl = flights.setdefault(name, Flight(name))
            if f.kind == "dji-mrk":
                fl.mrks.append(f)
            elif f.kind == "image":
                fl.photos.append(f)
            elif f.kind == "rinex-nav":
                fl.navs.append(f)
            elif f.kind in OBS_KINDS:
                fl.logs.append(f)
    in_flights = {f.path for f in files if f.path.startswith(FLIGHTS)}
    dji = [fl for fl in sorted(flights.values(), key=lambda x: x.name) if fl.mrks]
    for fl in sorted(flights.values(), key=lambda x: x.name):
        if not fl.mrks:
            problems.append(_problem("error", "flight-without-mrk",
                                     f"{fl.folder} has {_plural(len(fl.photos), 'photo')} and "
                                     f"{_plural(len(fl.logs), 'raw log')} but no Timestamp.MRK: upload the flight's "
                                     "*_Timestamp.MRK into it (the folder is not used without it)",
                                     [f.path for f in fl.photos[:5] + fl.logs]))
    # order the flights in time (their MRK), as the pipeline joins them
    dji.sort(key=lambda fl: (fl.mrk_span() or (float("inf"),))[0])
    # observation files with a role (a UBX or RTCM 3 log in nav/ is a navigation source only)
    obs = [f for f in files if f.kind in OBS_KINDS and f.path not in in_flights and not f.path.startswith("nav/")]
    unassigned = [f for f in obs if f.role not in ("rover", "base")]
    rover_std = [f for f in obs if f.role == "rover"]
    base = [f for f in obs if f.role == "base"]
    flight_logs = [f for fl in dji for f in fl.logs]
    rover = flight_logs or rover_std
    images_std = [f for f in by_kind.get("image", []) if f.path not in in_flights]
    flight_photos = [p for fl in dji for p in fl.photos]
    if unassigned:
        problems.append(_problem("error", "observation-role-unknown", "observation file(s) not assigned to the rover "
                                 "or the base: set their role", [f.path for f in unassigned]))
    if dji and flight_logs and rover_std:
        problems.append(_problem("warning", "rover-files-unused",
                                 f"{_plural(len(rover_std), 'file')} in rover/ not used: the DJI flights' own raw logs "
                                 "are the rover's", [f.path for f in rover_std]))
    if dji and images_std:
        problems.append(_problem("warning", "images-unused",
                                 f"{_plural(len(images_std), 'photo')} in images/ not used: with DJI flight folders "
                                 "the photos are those of the flights", [f.path for f in images_std[:50]]))

    # ---- rover
    flight_ref = {f.path: (fl.mrk_span() or (None,))[0] for fl in dji for f in fl.logs}
    any_ref = next((fl.mrk_span()[0] for fl in dji if fl.mrk_span()), None)
    rover_spans: list[tuple[float, float]] = []
    for f in rover:
        sp = file_span(f, flight_ref.get(f.path, any_ref))
        if sp:
            rover_spans.append(sp)
    # photos alone (RTK-tagged or with EXIF GPS): no raw log, no base, no rover/: the pipeline skips the PPK
    # and georeferences on the photos' own positions (georef_core.steps.gnss_solve.run_survey_gnss)
    photos_only = not rover and not base and not any(f.path.startswith("rover/") for f in files) \
        and bool(flight_photos if dji else images_std)
    if photos_only:
        problems.append(_problem("warning", "photos-only",
                                 "no raw GNSS log and no base station: no PPK; the photos' own positions (RTK tags "
                                 "or EXIF GPS) georeference the survey, to their accuracy. For PPK upload the "
                                 "aircraft's raw log (*_PPKRAW.bin) and the base observations"))
    elif not rover:
        if dji:
            problems.append(_problem("error", "missing-rover",
                                     "no rover raw log: the flight folders hold no *_PPKRAW.bin (RTCM 3), UBX or RINEX "
                                     "observation file, and rover/ is empty", [fl.folder for fl in dji]))
        else:
            problems.append(_problem("error", "missing-rover", "no rover (drone) GNSS observations"))
    elif len(rover) > 1:    # each flight's log dated by its own MRK
        j = join_report("rover", rover, lambda f: file_span(f, flight_ref.get(f.path, any_ref)))
        problems.append(_problem("info", "rover-files-joined", j.message + " (joined in time order)",
                                 [f.path for f in rover]))
        _overlap_problems("rover", j, problems)
    for fl in dji:
        if flight_logs and not fl.logs:
            problems.append(_problem("warning", "flight-without-raw-log",
                                     f"{fl.folder} has no raw GNSS log (*_PPKRAW.bin): its photos are positioned only "
                                     "where another flight's log covers them", [fl.mrks[0].path]))
    for f in rover + base:
        if f.kind == "rtcm3" and not (f.meta or {}).get("msm_messages", 1):
            problems.append(_problem("error", "no-observations",
                                     f"{f.path}: an RTCM 3 log without observation (MSM) messages "
                                     f"(messages {', '.join(sorted((f.meta or {}).get('message_counts', {})))})",
                                     [f.path]))

    # ---- base
    base_join = None
    if not base and not photos_only:
        problems.append(_problem("error", "missing-base", "no base station observations"))
    elif len(base) > 1:
        base_join = join_report("base", base, lambda f: file_span(f, any_ref))
        problems.append(_problem("info", "base-files-joined", base_join.message + " (joined in time order)",
                                 [f.path for f in base]))
        _overlap_problems("base", base_join, problems)

    # ---- navigation
    nav_rinex = [f for f in by_kind.get("rinex-nav", []) if f.path not in in_flights] + \
        [f for fl in dji for f in fl.navs]
    nav_sources = rover + base + [f for f in files if f.path.startswith("nav/") and f.kind in ("ubx", "rtcm3")]
    ubx_nav = any(f.kind == "ubx" for f in nav_sources)
    rtcm_eph = [f for f in nav_sources if f.kind == "rtcm3" and (f.meta or {}).get("ephemeris_messages")]
    nav_state = "files" if nav_rinex else ("logs" if (ubx_nav or rtcm_eph) else "none")
    few_eph = False
    if photos_only:
        nav_state = "photos-only"
    elif nav_state == "none":
        raw_no_eph = [f for f in rover + base if f.kind == "rtcm3"]
        if raw_no_eph:
            problems.append(_problem("error", "missing-navigation",
                                     f"PPKRAW without ephemerides and no navigation file: "
                                     f"{', '.join(_name(f) for f in raw_no_eph)} "
                                     f"{'carries' if len(raw_no_eph) == 1 else 'carry'} no ephemeris message "
                                     "(1019/1020/1042/1044/1045/1046): upload the RINEX navigation file of the day "
                                     "(e.g. the base's .nav or a CORS BRDC file)", [f.path for f in raw_no_eph]))
        else:
            problems.append(_problem("error", "missing-navigation", "no navigation (ephemeris) file: upload the RINEX "
                                     "navigation file of the day (e.g. from the base receiver or an IGS/CORS server)"))
    elif nav_state == "logs" and not ubx_nav:
        sats: dict[str, int] = {}
        for f in rtcm_eph:
            for sys_, n in ((f.meta or {}).get("ephemeris_satellites") or {}).items():
                sats[sys_] = max(sats.get(sys_, 0), int(n))
        observed = sorted({s_ for f in rover if f.kind == "rtcm3" for s_ in (f.meta or {}).get("systems", [])},
                          key="GREJC".find)
        few = [s_ for s_ in observed if sats.get(s_, 0) < MIN_EPHEMERIS_SATELLITES]
        if few:
            few_eph = True
            names = file_kinds.SYSTEM_NAMES
            have = ", ".join(f"{names.get(s_, s_)} {sats.get(s_, 0)}" for s_ in observed)
            problems.append(_problem("warning", "few-ephemerides",
                                     f"the RTCM 3 logs carry ephemerides of few satellites ({have}; fewer than "
                                     f"{MIN_EPHEMERIS_SATELLITES} for {', '.join(names.get(s_, s_) for s_ in few)}): "
                                     "satellites without an ephemeris are not used; upload the RINEX navigation file "
                                     "of the day for a stronger solution", [f.path for f in rtcm_eph]))

    # ---- rover / base time overlap
    base_spans = [sp for sp in (file_span(f, any_ref) for f in base) if sp]
    if rover and base:
        if rover_spans and len(rover_spans) == len(rover) and len(base_spans) == len(base):
            r_total = sum(b - a for a, b in _merge(rover_spans)) or 1e-9
            covered = sum(_covered(r, base_spans) for r in _merge(rover_spans))
            if covered <= 0:
                problems.append(_problem("error", "no-time-overlap",
                                         f"rover and base observations do not overlap in time: rover "
                                         f"{fmt_span(min(a for a, _ in rover_spans), max(b for _, b in rover_spans))}, "
                                         f"base {fmt_span(min(a for a, _ in base_spans), max(b for _, b in base_spans))}",
                                         [f.path for f in rover + base]))
            elif covered < 0.95 * r_total:
                problems.append(_problem("warning", "partial-time-overlap",
                                         f"the base covers {100 * covered / r_total:.0f} % of the rover's "
                                         f"{r_total / 60:.1f} min", [f.path for f in rover + base]))
            if base_join and base_join.gaps:
                inside = [g for g in base_join.gaps
                          if any(min(g[3], b) > max(g[2], a) for a, b in rover_spans)]
                if inside:
                    problems.append(_problem("warning", "base-gap",
                                             "the base has no data during the flight: " + "; ".join(
                                                 f"gap of {g[3] - g[2]:.0f} s between {g[0]} and {g[1]}"
                                                 for g in inside), [f.path for f in base]))
        else:
            problems.append(_problem("info", "time-span-unknown", "observation time spans could not be read before "
                                     "processing (compressed or UBX without raw measurements)",
                                     [f.path for f in rover + base if not file_span(f, flight_ref.get(f.path, any_ref))]))

    # ---- DJI flights
    cameras: dict[str, str] = {}
    for fl in dji:
        cam = check_flight(ctx, fl, problems)
        if cam:
            cameras[fl.name] = cam
    if len(set(cameras.values())) > 1:
        problems.append(_problem("warning", "flights-different-cameras",
                                 "the flights were made with different cameras (" + ", ".join(
                                     f"{n}: {c}" for n, c in cameras.items()) + "): each is calibrated on its own",
                                 [fl.folder for fl in dji if fl.name in cameras]))
    if len(dji) > 1:
        spans = [(fl.mrk_span(), fl) for fl in dji if fl.mrk_span()]
        parts = [f"{fl.name} ({fmt_span(*sp)}, {_plural(len(fl.photos), 'photo')})" for sp, fl in spans]
        gaps, overlaps = [], []
        for (sa, fa), (sb, fb) in zip(spans, spans[1:]):
            if sb[0] > sa[1]:
                gaps.append(f"gap of {sb[0] - sa[1]:.0f} s between {fa.name} and {fb.name}")
            else:
                overlaps.append((fa, fb, sa[1] - sb[0]))
        problems.append(_problem("info", "flights-joined",
                                 f"{len(dji)} flights joined in time order: {', '.join(parts)}"
                                 + (f"; {'; '.join(gaps)}" if gaps else ""), [fl.folder for fl in dji]))
        for fa, fb, d in overlaps:
            problems.append(_problem("warning", "flights-overlap",
                                     f"flights {fa.name} and {fb.name} overlap in time ({d:.0f} s): two aircraft, or "
                                     "the same flight twice?", [fa.mrks[0].path, fb.mrks[0].path]))

    # ---- camera events (standard layout)
    images = flight_photos if dji else images_std
    if not images:
        problems.append(_problem("warning", "no-images", "no images: only the GNSS trajectory can be computed"))
    elif not dji and not photos_only:
        _event_problems(by_kind, rover, images, problems)

    # ---- points
    pts = next((f for f in by_kind.get("points", []) if f.path == "gcp/points.csv"), None)
    if pts is None:
        problems.append(_problem("warning", "no-points", "no control/check points: no residual table can be computed"))
    elif not (pts.meta or {}).get("check"):
        problems.append(_problem("warning", "no-check-points", "no check point: accuracy cannot be verified "
                                 "independently (switch some points to check)", [pts.path]))
    gl = next((f for f in by_kind.get("gcp-list", [])), None)
    if gl is not None and images:
        names = {_name(f) for f in images}
        unknown = sorted(set((gl.meta or {}).get("images") or []) - names)
        if unknown:
            problems.append(_problem("warning", "gcp-list-unknown-images",
                                     f"gcp_list.txt measures {len(unknown)} image(s) that were not uploaded",
                                     unknown[:50]))
    if gl is not None:
        crs = str((gl.meta or {}).get("crs", "")).upper()
        if crs.startswith("EPSG:") and crs != site.crs.upper():
            problems.append(_problem("warning", "crs-mismatch", f"gcp_list.txt is in {crs}, the site in {site.crs}",
                                     [gl.path]))
    summary = summary_line(dji, images, rover, base, nav_rinex, nav_state, few_eph, pts)
    order = {"error": 0, "warning": 1, "info": 2}
    problems.sort(key=lambda p: order[p["severity"]])
    errors = sum(p["severity"] == "error" for p in problems)
    return {"survey_id": s.id, "ok": errors == 0, "errors": errors,
            "warnings": sum(p["severity"] == "warning" for p in problems), "problems": problems,
            "files": {k: len(v) for k, v in sorted(by_kind.items())}, "summary": summary}


def _overlap_problems(label: str, j: Joined, problems: list[dict]) -> None:
    for a, b in j.duplicates:
        problems.append(_problem("warning", "duplicate-files", f"{a} and {b} are the same file (same content): the "
                                 "data is used once", [a, b]))
    for a, b, d in j.overlaps:
        problems.append(_problem("warning", "files-overlap", f"{label} files {a} and {b} overlap in time "
                                 f"({fmt_duration(d)}): epochs present twice are taken from the earlier file", [a, b]))


def _event_problems(by_kind, rover, images, problems) -> None:
    events_file = next((f for f in by_kind.get("events", []) if f.path == "events.csv"), None)
    seen, rover_marks = set(), 0
    for f in rover:
        if f.sha256 not in seen:
            seen.add(f.sha256)
            rover_marks += int((f.meta or {}).get("event_marks", 0))
    if events_file is not None:
        listed = set((events_file.meta or {}).get("images") or [])
        n_events = int((events_file.meta or {}).get("events", 0))
        names = {_name(f) for f in images}
        if listed:
            missing = sorted(names - listed)
            if missing:
                problems.append(_problem("warning", "images-without-events",
                                         f"{len(missing)} image(s) have no camera event in events.csv",
                                         [f"images/{n}" for n in missing[:50]]))
            unknown = sorted(listed - names)
            if unknown:
                problems.append(_problem("warning", "events-without-images",
                                         f"{len(unknown)} event(s) name images that were not uploaded", unknown[:50]))
        elif n_events != len(images):
            problems.append(_problem("warning", "images-without-events",
                                     f"{len(images)} images but {n_events} camera events in events.csv"))
    elif rover_marks:
        if rover_marks != len(images):
            problems.append(_problem("warning", "images-without-events",
                                     f"{len(images)} images but {rover_marks} event marks in the rover file"))
    else:
        problems.append(_problem("warning", "images-without-events", "no camera events: neither events.csv nor "
                                 "event marks in the rover observations; images will be matched by EXIF time"))


def summary_line(dji, images, rover, base, nav_rinex, nav_state, few_eph, pts) -> str:
    parts = []
    if dji:
        parts.append(_plural(len(dji), "flight"))
    parts.append(_plural(len(images), "photo") if images else "no photos")
    if dji:
        parts.append(f"MRK {sum(fl.exposures for fl in dji)} exposures")
    parts.append(_rover_phrase(rover) if rover else "no rover log")
    parts.append(f"base: {_count_phrase(base)}" if base else "no base")
    if nav_state == "files":
        parts.append(f"navigation: {_plural(len(nav_rinex), 'RINEX file')}")
    elif nav_state == "logs":
        parts.append("navigation file advised (few ephemerides in the logs)" if few_eph
                     else "no navigation file needed")
    elif nav_state == "photos-only":
        parts.append("photo positions only (no PPK)")
    else:
        parts.append("no navigation file")
    if pts is not None:
        m = pts.meta or {}
        parts.append(f"{_plural(int(m.get('points', 0)), 'point')} ({m.get('control', 0)} control, "
                     f"{m.get('check', 0)} check)")
    return ", ".join(parts)
