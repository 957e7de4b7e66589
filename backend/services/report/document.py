"""The survey report (PDF, ReportLab) drawn from a run folder and what the platform knows of the run (meta):
cover (project, company, survey date, CRS and vertical datum, software), flight and equipment, processing
settings (read from the step specs' help texts), GNSS quality with the fix status over time, the lever arm
and trigger delay in words, the check-point residual table with its verdict against the site tolerance and
the formal accuracy statement (ASPRS Edition 2, 2023: georef_core.adjustment.accuracy_standard), maps
(orthophoto with the surveyed points, DSM hillshade, cut/fill to design), the stockpile inventory with
uncertainties, and the state of every step.

Everything shown comes from users (site, survey, stockpile and point names) or from the processing
(warnings, step errors): ReportLab's Paragraph reads its text as markup (<img src="..."/> embeds a file of
the server, a stray "<" fails the build), so every piece of text is escaped before it enters one (text.esc),
and file paths are reduced to file names (text.scrub): the report never shows the worker's folders. The
only images are the ones the report draws itself from the run's rasters."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..display import format_flight_time, format_volume, format_volume_pm, material_label
from . import figures, run_data
from .text import cm, delay_sentence, esc, finite, fmt, lever_arm_sentence, plain, scrub

GREEN, AMBER, RED = (0.16, 0.55, 0.25), (0.85, 0.55, 0.05), (0.78, 0.12, 0.12)


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("georef")
    except Exception:           # noqa: BLE001 - not installed as a distribution (a source checkout)
        from georef_core import __version__

        return __version__


def crs_name(crs: str | None) -> str:
    """'EPSG:32653 (WGS 84 / UTM zone 53N)'; the code alone when pyproj does not know it."""
    if not crs:
        return "not set"
    try:
        from pyproj import CRS

        return f"{crs} ({CRS.from_user_input(crs).name})"
    except Exception:           # noqa: BLE001
        return str(crs)


class _Story:
    """The flowables of the report and the small vocabulary the sections write with."""

    def __init__(self, run_dir: Path):
        from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet

        self.run_dir = run_dir
        self.styles = getSampleStyleSheet()
        self.small = ParagraphStyle("small", parent=self.styles["BodyText"], fontSize=8, leading=10)
        self.head = ParagraphStyle("head", parent=self.small, fontName="Helvetica-Bold")
        self.right = ParagraphStyle("right", parent=self.small, alignment=2)
        self.flow: list = []
        self.sections: list[str] = []
        self.number = 0

    def add(self, flowable):
        self.flow.append(flowable)

    def h(self, text: str, keep: bool = True):
        from reportlab.lib.units import mm
        from reportlab.platypus import CondPageBreak, Paragraph, Spacer

        self.number += 1
        self.flow.append(CondPageBreak(40 * mm))
        self.flow.append(Spacer(1, 3 * mm))
        self.flow.append(Paragraph(f"{self.number}. {esc(text)}", self.styles["Heading2"]))

    def h3(self, text: str):
        from reportlab.platypus import Paragraph

        self.flow.append(Paragraph(esc(text), self.styles["Heading4"]))

    def p(self, text: str, style=None, colour=None):
        """A paragraph of plain text (escaped here: never markup)."""
        from reportlab.platypus import Paragraph

        body = esc(text)
        if colour is not None:
            body = f'<font color="#{"".join(f"{int(255 * c):02x}" for c in colour)}">{body}</font>'
        self.flow.append(Paragraph(body, style or self.styles["BodyText"]))

    def para(self, text: str, style=None):
        from reportlab.platypus import Paragraph

        return Paragraph(esc(text), style or self.small)

    def table(self, rows, widths=None, align_right_from: int = 1, styles_extra=()):
        from reportlab.lib import colors
        from reportlab.platypus import Table, TableStyle

        rows = [[plain(v) if isinstance(v, str) else v for v in r] for r in rows]
        t = Table(rows, colWidths=widths, repeatRows=1, hAlign="LEFT")
        t.setStyle(TableStyle([("FONT", (0, 0), (-1, 0), "Helvetica-Bold", 8), ("FONT", (0, 1), (-1, -1), "Helvetica", 8),
                               ("GRID", (0, 0), (-1, -1), 0.25, colors.grey),
                               ("BACKGROUND", (0, 0), (-1, 0), colors.Color(0.9, 0.9, 0.9)),
                               ("VALIGN", (0, 0), (-1, -1), "TOP"),
                               ("ALIGN", (align_right_from, 1), (-1, -1), "RIGHT"), *styles_extra]))
        self.flow.append(t)

    def spacer(self, h_mm: float = 2):
        from reportlab.lib.units import mm
        from reportlab.platypus import Spacer

        self.flow.append(Spacer(1, h_mm * mm))


# ------------------------------------------------------------------------------------------------ sections


def _cover(s: _Story, meta: dict, ctx: dict) -> None:
    from reportlab.lib.units import mm
    from reportlab.platypus import Paragraph

    st = s.styles
    s.add(Paragraph("Accuracy report: " + esc(meta.get("survey", "survey")), st["Title"]))
    if meta.get("title"):
        s.add(Paragraph(esc(meta["title"]), st["Heading3"]))
    s.add(Paragraph(
        f"Site <b>{esc(meta.get('site', ''))}</b>, project CRS {esc(meta.get('crs', ''))}"
        + (f", vertical datum {esc(meta['vertical_datum'])}" if meta.get("vertical_datum") else ", ellipsoidal heights")
        + f". Flight: {esc(format_flight_time(meta.get('flown_at'), meta.get('flown_at_source')))}. Processing run "
        f"{esc(meta.get('run_number', '?'))}, report made {ctx['made']:%Y-%m-%d %H:%M} UTC.", st["BodyText"]))
    s.spacer(3)
    rows = [["Project", "this survey"],
            ["Company", meta.get("company") or "not given"],
            ["Site", meta.get("site", "")],
            ["Survey", meta.get("survey", "")],
            ["Survey date", format_flight_time(meta.get("flown_at"), meta.get("flown_at_source"))],
            ["Coordinate reference system", crs_name(meta.get("crs"))],
            ["Heights", (f"vertical datum {meta['vertical_datum']}" + (f", geoid {meta['geoid']}" if meta.get("geoid") else ""))
             if meta.get("vertical_datum") else "ellipsoidal heights (WGS 84 ellipsoid)"],
            ["Processing", f"run {meta.get('run_number', '?')}, Georef {software_version()}"],
            ["Report made", f"{ctx['made']:%Y-%m-%d %H:%M} UTC"]]
    s.table([[a, s.para(b) if isinstance(b, str) else b] for a, b in rows], widths=[45 * mm, 125 * mm],
            align_right_from=99)
    s.sections.append("cover")
    # the verdicts first: what a site manager reads
    s.spacer(3)
    s.add(Paragraph("Results at a glance", st["Heading3"]))
    for line, colour in ctx["glance"]:
        s.p(line, colour=colour)


def _equipment(s: _Story, ctx: dict) -> None:
    from reportlab.lib.units import mm

    gs, geo, dense = ctx["gnss"], ctx["georef"], ctx["dense"]
    s.h("Flight and equipment")
    rows = [["item", "what this survey used"]]
    if geo:
        im = geo.get("images") or {}
        rows.append(["Photos", f"{im.get('total', '-')} photos, {im.get('registered', '-')} oriented, "
                               f"{im.get('with_gnss', '-')} with a GNSS camera position"
                     + (f"; {len(im['left_out'])} left out" if im.get("left_out") else "")])
        for c in geo.get("cameras") or []:
            vals = c.get("values") or []
            sig = c.get("sigma") or {}
            f_px = vals[0] if vals else None
            calib = (f"focal length {fmt(f_px, 1)} px ± {fmt(sig.get('f'), 1)} px, principal point "
                     f"{fmt(vals[1], 1)}, {fmt(vals[2], 1)} px" if len(vals) >= 3 else "")
            opts = geo.get("options") or {}
            how = ("held at a given calibration" if opts.get("fixed_intrinsics") else
                   f"self-calibrated in the adjustment ({geo.get('camera_model', 'brown')} model)")
            rows.append([f"Camera {c.get('id', '')}", f"{c.get('label') or 'camera'}: {c.get('n_images', '-')} photos; "
                                                      f"{calib}; {how}"])
        rs = geo.get("rolling_shutter") or {}
        if rs:
            rows.append(["Shutter", "rolling shutter, modelled" if rs.get("modelled") else
                         ("rolling shutter" if rs.get("rolling_shutter") else "global shutter or not known")
                         + (f" ({scrub(rs.get('source'), s.run_dir)})" if rs.get("source") else "")])
    if gs:
        inp = gs.get("inputs") or {}
        names = lambda k: ", ".join(Path(str(x)).name for x in (inp.get(k) or [])) or "-"  # noqa: E731
        o = gs.get("options") or {}
        rows.append(["GNSS rover (aircraft)", f"observations {names('rover')}"
                     + (f"; camera triggers: {scrub(gs['events'].get('source'), s.run_dir)}"
                        if (gs.get("events") or {}).get("source") else "")])
        bp = gs.get("base_position") or {}
        rows.append(["GNSS base", f"observations {names('base')}; position: "
                     + (scrub(bp.get("text"), s.run_dir) or scrub(bp.get("source"), s.run_dir) or "-")])
        if o:
            rows.append(["GNSS signals", f"{o.get('n_bands', '-')} frequency band(s), systems "
                                         f"{', '.join(o.get('systems') or []) or '-'}, elevation mask "
                                         f"{fmt(o.get('elmask_deg'), 0)} deg"])
        span = gs.get("time_span") or {}
        if finite(span.get("first_gps_time_s")) and finite(span.get("last_gps_time_s")):
            dur = span["last_gps_time_s"] - span["first_gps_time_s"]
            rows.append(["Flight", f"{(gs.get('events') or {}).get('count', '-')} camera triggers over "
                                   f"{dur / 60:.1f} min ({_gps_utc(span['first_gps_time_s'])} to "
                                   f"{_gps_utc(span['last_gps_time_s'])} UTC)"])
    if dense:
        cell, gsd = dense.get("dsm_resolution_m"), dense.get("gsd_m")
        rows.append(["Surface", (f"ground sample distance {cm(gsd)}; " if finite(gsd) else "")
                     + (f"DSM cell {cm(cell)}" if finite(cell) else "DSM")
                     + (f"; {dense['points']['written']:,} dense points" if finite((dense.get("points") or {}).get("written"))
                        else "")])
    if len(rows) == 1:
        s.p("No equipment information in this run (no GNSS or georeferencing results).")
        return
    s.table([rows[0]] + [[a, s.para(b)] for a, b in rows[1:]], widths=[38 * mm, 132 * mm], align_right_from=99)
    s.sections.append("equipment")


def _gps_utc(gps_s: float) -> str:
    # GPS time runs ahead of UTC by the leap seconds (18 s since 2017)
    t = datetime.fromtimestamp(run_data.GPS_EPOCH_UNIX_S + gps_s - 18.0, tz=timezone.utc)
    return f"{t:%Y-%m-%d %H:%M:%S}"


def _option_value(o, v) -> str:
    if v is None:
        return "automatic"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (list, tuple)):
        text = ", ".join(f"{x:g}" if isinstance(x, (int, float)) and not isinstance(x, bool) else str(x) for x in v)
    elif isinstance(v, float):
        text = f"{v:g}"
    elif isinstance(v, dict):
        text = ", ".join(f"{k} {x}" for k, x in v.items())
    else:
        text = str(v)
    return f"{text} {o.unit}" if o.unit and text else text


def _settings(s: _Story, meta: dict) -> None:
    from reportlab.lib.units import mm

    from .. import steps_catalog

    s.h("Processing settings")
    settings = meta.get("settings") or {}
    ran = [st["name"] for st in meta.get("steps") or [] if st.get("name") != "report"]
    if not ran:
        s.p("The steps of this run are not known to the report.")
        return
    s.p("Each step's settings as its declaration describes them: the settings given for this run, then the main "
        "settings at their defaults (advanced settings are listed only when given).", s.small)
    rows = [["step", "setting", "value", ""]]
    for name in ran:
        spec = steps_catalog.BY_NAME.get(name)
        if spec is None:
            continue
        given = settings.get(name) or {}
        first = True
        for o in spec.options:
            if o.name in given:
                v, how = given[o.name], "given"
            elif not o.advanced and o.kind != "object":
                v, how = o.default, "default"
            else:
                continue
            help_text = (o.help or o.name)
            rows.append([s.para(spec.title) if first else "", s.para(help_text[0].upper() + help_text[1:]),
                         s.para(_option_value(o, v)), how])
            first = False
        if first:
            rows.append([s.para(spec.title), s.para("no settings"), "", ""])
    s.table(rows, widths=[34 * mm, 92 * mm, 32 * mm, 12 * mm], align_right_from=99)
    s.sections.append("settings")


def _gnss(s: _Story, ctx: dict) -> None:
    from reportlab.lib.units import mm

    gs = ctx["gnss"]
    s.h("GNSS trajectory (PPK)")
    if not gs:
        s.p("No GNSS solution in this run.")
        return
    s.sections.append("gnss")
    fr = gs.get("fix_rate")
    rows = [["epochs", "fixed", "float", "single", "fix rate"],
            [gs.get("epochs", "-"), gs.get("fix", "-"), gs.get("float", "-"), gs.get("single", "-"),
             fmt(100 * fr, 1, " %") if finite(fr) else "-"]]
    s.table(rows)
    _gnss_equipment(s, gs.get("equipment"))
    ev = gs.get("events") or {}
    if ev:
        s.p(f"Camera triggers: {ev.get('count', '-')} events, {ev.get('fixed', '-')} on fixed epochs, "
            f"{ev.get('without_solution', 0)} without solution.")
    if finite(fr):
        s.p("A fixed solution is centimetre-accurate; float epochs are decimetre-level and single epochs metre-level. "
            + ("Every epoch is fixed." if fr >= 0.9999 else f"{100 * (1 - fr):.1f} % of the epochs are not fixed."
               + (" The camera triggers on them are the ones to look at." if ev.get("count") else "")),
            s.small)
    trig = ctx["triggers"]
    sd = [(r.get("sd_x_m"), r.get("sd_y_m"), r.get("sd_z_m")) for r in trig]
    sd = [x for x in sd if None not in x and all(finite(v) for v in x)]
    if sd:
        s3 = [math.sqrt(a * a + b * b + c * c) for a, b, c in sd]
        s.p(f"Antenna position precision at the triggers (1 sigma, 3D): mean {fmt(1000 * sum(s3) / len(s3), 1)} mm,"
            f" max {fmt(1000 * max(s3), 1)} mm over {len(s3)} events.")
    ep = ctx["epochs"]
    if ep is not None and len(ep["unix_s"]) > 1:
        gps_trig = np.array([r["gps_time_s"] for r in trig if finite(r.get("gps_time_s"))], float)
        # the .pos times are GPST calendar times: the same scale as the triggers' GPS seconds
        trig_unix = gps_trig + run_data.GPS_EPOCH_UNIX_S if ep["time_scale"] == "GPST" else gps_trig + \
            run_data.GPS_EPOCH_UNIX_S - 18.0
        t0 = datetime.fromtimestamp(float(ep["unix_s"][0]), tz=timezone.utc)
        d = figures.fix_status_drawing(ep["unix_s"], ep["status"], ep["sigma3d_m"], trig_unix, 170 * mm,
                                       f"{t0:%Y-%m-%d %H:%M:%S} {ep['time_scale']}")
        s.spacer(1)
        s.add(d)
        s.p("Fix status of every epoch (green fixed, amber float, red single) and the antenna position's 3D "
            "sigma over the flight.", s.small)
        s.sections.append("gnss_plot")
    for w in (gs.get("warnings") or [])[:10]:
        s.p(f"Note: {scrub(w, s.run_dir)}", s.small)


def _gnss_equipment(s: _Story, eq: dict | None) -> None:
    """The rover's and base's receiver and antenna models as their observation files state them (the gnss
    step's summary "equipment": RINEX header, RTCM 1033, UBX MON-VER; else the file format)."""
    from reportlab.lib.units import mm

    from georef_core.gnss.receiver_equipment import equipment_text

    s.spacer(1)
    if not eq:
        s.p("Receiver and antenna models: not recorded in this run's GNSS summary.", s.small)
        return
    rows = [["receiver", "model, as its observation file states it"]]
    for role, label in (("rover", "Rover (aircraft)"), ("base", "Base station")):
        if eq.get(role):
            rows.append([label, s.para(equipment_text(eq[role]))])
    s.table(rows, widths=[38 * mm, 132 * mm], align_right_from=99)
    s.sections.append("gnss_equipment")


def _georef(s: _Story, ctx: dict) -> None:
    la = ctx["lever"]
    s.h("Georeferencing: lever arm and trigger delay")
    if not la:
        s.p("Not estimated in this run (georeferencing step not run or unavailable).")
        return
    s.sections.append("lever_arm")
    est = la.get("estimated") or {}
    s.p(lever_arm_sentence(la.get("lever_arm_cam_m"), la.get("lever_arm_sigma_m"), est.get("lever_arm")))
    s.p(delay_sentence(la.get("delay_s"), la.get("delay_sigma_s") if est.get("delay", True) else None))
    if finite(la.get("readout_s")):
        s.p(f"The rolling shutter reads the image out in {la['readout_s'] * 1000:.1f} ms"
            + (f" ± {la['readout_sigma_s'] * 1000:.1f} ms" if finite(la.get("readout_sigma_s")) else "") + ".")
    geo = ctx["georef"] or {}
    aa = geo.get("absolute_accuracy") or {}
    if aa.get("text"):
        s.p("What the absolute position rests on: " + scrub(aa["text"], s.run_dir) + ".", s.small)
    adj = geo.get("adjustment") or {}
    if adj:
        used = adj.get("control_points_used") or []
        s.p(f"Adjustment mode {geo.get('mode', adj.get('mode', '-'))}: "
            f"{len(used)} control point{'s' if len(used) != 1 else ''} used"
            + (f" ({', '.join(str(u) for u in used)})" if used else "")
            + (f", reprojection RMS {fmt(adj.get('rms_reprojection_px'), 2)} px" if finite(adj.get("rms_reprojection_px")) else "")
            + ".", s.small)
    dom = (geo.get("doming") or {}).get("camera_positions") or {}
    if dom.get("significant"):
        s.p(f"Warning: a significant doming of the block ({fmt(1000 * dom.get('doming_m', float('nan')), 1)} mm).",
            colour=AMBER)


def tolerance_verdict(points: list[dict], tol_h_m, tol_v_m) -> dict:
    """Each check point's horizontal |d| against the horizontal tolerance and |dz| against the vertical one
    (the browser's rule: within, within 1.5x: marginal, beyond: outside); the survey passes when every check
    point is within."""
    if not (finite(tol_h_m) and finite(tol_v_m)):
        return {"set": False}
    out = []
    for q in points:
        dx, dy, dz = q.get("dx_m"), q.get("dy_m"), q.get("dz_m")
        if None in (dx, dy, dz):
            continue
        h = math.hypot(dx, dy)
        worst = max(h / tol_h_m, abs(dz) / tol_v_m)
        out.append((q.get("name"), "within" if worst <= 1.0 else "marginal" if worst <= 1.5 else "outside"))
    bad = [n for n, v in out if v != "within"]
    return {"set": True, "per_point": dict(out), "n": len(out), "outside": bad, "pass": bool(out) and not bad}


def _residuals(s: _Story, meta: dict, ctx: dict) -> None:
    from reportlab.lib import colors
    from reportlab.lib.units import mm
    from reportlab.platypus import KeepTogether, Paragraph, Table, TableStyle

    s.h("Check points: residuals, tolerance and accuracy statement")
    res = ctx["residuals"]
    if not res:
        s.p("No residual table in this run (georeferencing step not run or unavailable, or no check point).")
        return
    s.sections.append("residuals")
    tol = ctx["tolerance"]
    verdict = ctx["verdict"]
    rows = [["point", "role", "dE (m)", "dN (m)", "dh (m)", "|d| (m)", "tolerance"]]
    extra = []
    for i, q in enumerate(res["points"], start=1):
        v = (verdict.get("per_point") or {}).get(q.get("name"), "-") if verdict.get("set") else "-"
        rows.append([q.get("name"), q.get("role", ""), fmt(q.get("dx_m")), fmt(q.get("dy_m")), fmt(q.get("dz_m")),
                     fmt(q.get("d_m")), v])
        if v in ("marginal", "outside"):
            extra.append(("TEXTCOLOR", (6, i), (6, i), colors.Color(*(AMBER if v == "marginal" else RED))))
    s.table(rows, styles_extra=extra)
    s.p("d = estimated - surveyed, in the project CRS: dE easting, dN northing, dh height.", s.small)
    st = res["stats"]
    if st.get("n"):
        rows = [["", "dE", "dN", "dh", "|d|"]]
        for stat, label in (("mean_m", "mean"), ("std_m", "std"), ("rmse_m", "rmse"), ("max_abs_m", "max abs")):
            rows.append([label] + [fmt((st.get(c) or {}).get(stat)) for c in ("dx", "dy", "dz")]
                        + [fmt((st.get("3d") or {}).get("max_m" if stat == "max_abs_m" else stat))])
        s.spacer(2)
        s.table(rows)
        s.p("Statistics in metres; std is the sample standard deviation (n - 1).", s.small)
    prev = meta.get("previous") or {}
    rmse_d = ((st.get("3d") or {}).get("rmse_m")) if st.get("n") else None
    if finite(rmse_d) and finite(prev.get("rmse_d_m")):
        s.p(f"3D RMSE {fmt(rmse_d)} m; previous run {prev.get('run_number')}: {fmt(prev['rmse_d_m'])} m.")
    # the verdict against the site tolerance
    s.h3("Verdict against the site tolerance")
    if not verdict.get("set"):
        s.p("No tolerance set for this site: the residuals are not judged.")
    elif verdict["n"] == 0:
        s.p("No check point: the survey cannot be judged against the site tolerance.", colour=AMBER)
    else:
        th, tv = tol
        if verdict["pass"]:
            s.p(f"WITHIN TOLERANCE: all {verdict['n']} check point{'s' if verdict['n'] != 1 else ''} within the site "
                f"tolerance of {cm(th)} horizontally and {cm(tv)} vertically.", colour=GREEN)
        else:
            s.p(f"OUTSIDE TOLERANCE: {len(verdict['outside'])} of {verdict['n']} check points beyond the site "
                f"tolerance of {cm(th)} horizontally and {cm(tv)} vertically: "
                f"{', '.join(str(n) for n in verdict['outside'])}.", colour=RED)
        hz, vz = (st.get("horizontal") or {}).get("rmse_m"), (st.get("dz") or {}).get("rmse_m")
        s.p(f"Horizontal RMSE {cm(hz)}, vertical RMSE {cm(vz)}. Rule: a point is within when its horizontal "
            "residual and its height residual are each within their tolerance; marginal up to 1.5 times.", s.small)
    s.sections.append("tolerance")
    # the formal statement
    a = ctx["asprs"]
    if a is None:
        return
    start = len(s.flow)
    s.h3("Accuracy statement (ASPRS Positional Accuracy Standards, Edition 2, 2023)")
    box = []
    for ax in (a.horizontal, a.vertical):
        box.append([Paragraph(esc(ax.statement), s.styles["BodyText"])])
    t = Table(box, colWidths=[170 * mm], hAlign="LEFT")
    t.setStyle(TableStyle([("BOX", (0, 0), (-1, -1), 0.8, colors.Color(0.2, 0.2, 0.2)),
                           ("BACKGROUND", (0, 0), (-1, -1), colors.Color(0.96, 0.96, 0.93)),
                           ("LEFTPADDING", (0, 0), (-1, -1), 6), ("RIGHTPADDING", (0, 0), (-1, -1), 6)]))
    s.add(t)
    s.spacer(1)
    sh, sv = ctx["check_sigma_m"]
    rows = [["", "horizontal (RMSE_H)", "vertical (RMSE_V)"],
            ["tested from the residuals", cm(_m(a.horizontal.measured_rmse_cm)), cm(_m(a.vertical.measured_rmse_cm))],
            ["check points' own survey", cm(_m(a.horizontal.survey_rmse_cm)), cm(_m(a.vertical.survey_rmse_cm))],
            ["product (both combined)", cm(_m(a.horizontal.product_rmse_cm)), cm(_m(a.vertical.product_rmse_cm))],
            ["class met", _class_text(a.horizontal.class_cm), _class_text(a.vertical.class_cm)],
            ["check points", f"{a.n_check_points} (the standard asks for at least {a.min_check_points})", ""]]
    s.table(rows, widths=[50 * mm, 60 * mm, 60 * mm])
    s.p(f"RMSE_H = sqrt(RMSE_E² + RMSE_N²); the check points' survey accuracy ({cm(sh)} per horizontal axis, "
        f"{cm(sv)} vertical: the georeferencing setting 'control point survey sigma') is added in quadrature, "
        "RMSE(product) = sqrt(RMSE(tested)² + RMSE(survey)²), and must be at least two times better than the class. "
        "Vertical accuracy is non-vegetated (targets on open ground).", s.small)
    for n in a.notes:
        s.p(n, s.small, colour=AMBER)
    s.flow[start:] = [KeepTogether(s.flow[start:])]
    s.sections.append("accuracy_statement")


def _m(v_cm):
    return None if v_cm is None else v_cm / 100.0


def _class_text(c) -> str:
    return f"{c:g} cm class" if c is not None else "none"


def _maps(s: _Story, meta: dict, ctx: dict, survey_dir: Path | None) -> None:
    from reportlab.lib.units import mm

    run_dir = s.run_dir
    ortho_p, dsm_p, diff_p = run_dir / "dense" / "ortho.tif", run_dir / "dense" / "dsm.tif", run_dir / "design" / "difference.tif"
    if not (ortho_p.exists() or dsm_p.exists() or diff_p.exists()):
        return
    s.h("Maps")
    outlines = run_data.outline_rings(meta.get("stockpile_outlines"))
    width = 170 * mm
    drawn = False
    if ortho_p.exists():
        g = figures.read_grid(ortho_p, 1100)
        if g is not None:
            pts = run_data.surveyed_points(survey_dir, meta.get("crs"))
            _image(s, figures.ortho_map(g, pts, outlines), g, width, 120 * mm)
            n_check = sum(1 for p in pts if p["role"] == "check")
            s.p(f"Orthophoto, north up, {g.width_m:.0f} m x {g.height_m:.0f} m, cell {cm(g.full_cell_m)}. "
                f"Red circles: check points ({n_check}); blue triangles: control points ({len(pts) - n_check})"
                + ("; yellow: stockpile outlines" if outlines else "") + ".", s.small)
            drawn = True
    if dsm_p.exists():
        g = figures.read_grid(dsm_p, 900, bands=[1])
        if g is not None:
            png, lo, hi = figures.hillshade_map(g, outlines)
            _image(s, png, g, width, 100 * mm)
            s.p(f"Surface model (DSM): height colours from {lo:.2f} m (green) to {hi:.2f} m (white) over its hillshade, "
                f"north up, {g.width_m:.0f} m x {g.height_m:.0f} m, cell {cm(g.full_cell_m)}"
                + ("; black: stockpile outlines" if outlines else "") + ".", s.small)
            drawn = True
    if diff_p.exists():
        g = figures.read_grid(diff_p, 900, bands=[1])
        tol = (ctx["design"] or {}).get("tolerance_m")
        if g is not None:
            _image(s, figures.cut_fill_map(g, tol if finite(tol) else 0.05), g, width, 100 * mm)
            _legend(s, figures.CUT_FILL_COLOURS)
            s.p(f"Cut/fill to design: surveyed minus design, tolerance ± {cm(tol if finite(tol) else 0.05)}.", s.small)
            drawn = True
    if drawn:
        s.sections.append("maps")
    else:
        s.p("The rasters of this run could not be read: no maps.")


def _image(s: _Story, data: bytes, g, max_w: float, max_h: float) -> None:
    import io

    from reportlab.platypus import Image

    w_px, h_px = g.data.shape[2], g.data.shape[1]
    scale = min(max_w / w_px, max_h / h_px)
    s.add(Image(io.BytesIO(data), width=w_px * scale, height=h_px * scale, hAlign="LEFT"))


def _legend(s: _Story, colours: dict) -> None:
    from reportlab.lib import colors
    from reportlab.lib.units import mm
    from reportlab.platypus import Table, TableStyle

    rows = [["", name] for name in colours]
    t = Table(rows, colWidths=[6 * mm, 100 * mm], hAlign="LEFT", rowHeights=[4 * mm] * len(rows))
    cmds = [("FONT", (0, 0), (-1, -1), "Helvetica", 7), ("VALIGN", (0, 0), (-1, -1), "MIDDLE"),
            ("TOPPADDING", (0, 0), (-1, -1), 0), ("BOTTOMPADDING", (0, 0), (-1, -1), 0)]
    for i, c in enumerate(colours.values()):
        cmds.append(("BACKGROUND", (0, i), (0, i), colors.Color(*(v / 255 for v in c))))
    t.setStyle(TableStyle(cmds))
    s.add(t)


def _volumes(s: _Story, meta: dict, ctx: dict) -> None:
    from reportlab.lib.units import mm

    s.h("Stockpile volumes and inventory")
    vols = meta.get("volumes")
    if vols is None:
        vols = run_data.volumes_from_file(s.run_dir)
    if not vols:
        s.p("No volumes in this run (no stockpile defined, or the surface step did not run).")
        return
    s.sections.append("volumes")
    pv = (meta.get("previous") or {}).get("volumes") or {}
    inv = _inventory(meta, vols)
    by_name = {r["stockpile"]: r for r in inv.rows} if inv is not None else {}
    rows = [[s.para(h, s.head) for h in ("stockpile", "material", "base", "volume (m3)", "density (t/m3)",
                                         "tonnage (t)", "previous (m3)", "change (m3)")]]
    for v in vols:
        # one rule for every volume (display.py, as in the browser): decimals from the uncertainty
        before, sigma, vol = pv.get(v["name"]), v.get("sigma_m3"), v.get("volume_m3")
        r = by_name.get(v["name"]) or {}
        dens, tonnes = "-", "-"
        if finite(r.get("density_t_m3")):
            dens = f"{r['density_t_m3']:.2f}" + (f" ± {r['density_sigma_t_m3']:.2f}" if r.get("density_sigma_t_m3")
                                                 else "") + ("" if r.get("density_source", "").startswith("given")
                                                             else " (default)")
        if finite(r.get("tonnes_t")):
            tonnes = format_volume_pm(r["tonnes_t"], r.get("tonnes_sigma_t") or None)
        rows.append([v["name"], material_label(v.get("material")), v.get("base", ""),
                     format_volume_pm(vol, sigma), s.para(dens, s.right), tonnes, format_volume(before, sigma),
                     format_volume(vol - before, sigma) if (before is not None and finite(vol)) else "-"])
    tot = inv.totals if inv is not None else {}
    n_t = sum(1 for r in by_name.values() if finite(r.get("tonnes_t")))
    if len(vols) > 1 and finite(tot.get("volume_m3")):
        rows.append(["total", "", "", format_volume_pm(tot["volume_m3"], tot.get("volume_sigma_m3") or None), "",
                     (format_volume_pm(tot["tonnes_t"], tot.get("tonnes_sigma_t") or None)
                      + ("" if n_t == len(vols) else " *")) if finite(tot.get("tonnes_t")) else "-", "", ""])
    s.table(rows, widths=[25 * mm, 22 * mm, 13 * mm, 24 * mm, 26 * mm, 24 * mm, 18 * mm, 18 * mm], align_right_from=3)
    s.p("Volumes in cubic metres (m3) with their 1-sigma uncertainty (DSM noise, height bias, base model). Tonnage "
        "in tonnes (t) = density x volume, its sigma from both (sigma_T² = (rho sigma_V)² + (V sigma_rho)²); the "
        "stockpile's own density, else an indicative default of its material (marked: a weighbridge ticket or a "
        "density test should replace it); a density given without an uncertainty is taken as exact"
        + (f"; * the total tonnage is that of the {n_t} of {len(vols)} piles with a density" if 0 < n_t < len(vols)
           else "") + ". Totals add a survey-wide height bias and a shared density linearly, the rest in "
        "quadrature (the site inventory's rules: docs/deliverables.md).", s.small)
    design = ctx["design"]
    if design and not design.get("skipped") and finite(design.get("cut_m3")):
        unc = design.get("uncertainty") or {}
        sig = lambda k: (unc.get(k) or {}).get("sigma_m3")  # noqa: E731
        s.h3("Cut/fill to design")
        rows = [["", "cut (m3)", "fill (m3)", "net (m3)", "on grade"],
                [(design.get("polygon") or {}).get("name") or "design area",
                 format_volume_pm(design["cut_m3"], sig("cut_m3")), format_volume_pm(design.get("fill_m3"), sig("fill_m3")),
                 format_volume_pm(design.get("net_m3"), sig("net_m3")),
                 fmt(100 * (design.get("on_grade") or {}).get("share", float("nan")), 1, " %")]]
        s.table(rows)
        s.p(f"Cut: surveyed above design (to remove); fill: below design (to place); on grade: within ± "
            f"{cm(design.get('tolerance_m'))}.", s.small)
        s.sections.append("design")


def _inventory(meta: dict, vols: list[dict]):
    """This survey's piles through the site inventory's pure function (georef_core.deliverables.inventory):
    tonnes with the density's uncertainty (the material's default when the pile has none) and correlated
    totals; None when it is not installed."""
    try:
        from georef_core.deliverables.inventory import Measurement, Pile, build_inventory
    except ImportError:
        return None
    try:
        day = datetime.fromisoformat(str(meta.get("flown_at")).replace("Z", "+00:00")).date()
    except ValueError:
        day = datetime.now(timezone.utc).date()
    piles = [Pile(v["name"], v.get("material") or "", v.get("density_t_m3"), v.get("density_sigma_t_m3"),
                  [Measurement(day, str(meta.get("survey", "")), float(v["volume_m3"]), float(v.get("sigma_m3") or 0.0),
                               v.get("height_bias_m3"))])
             for v in vols if finite(v.get("volume_m3"))]
    try:
        return build_inventory(piles, day)
    except Exception:           # noqa: BLE001 - the volumes are still shown, without tonnage
        return None


def _steps(s: _Story, meta: dict) -> None:
    from reportlab.lib.units import mm
    from reportlab.platypus import Paragraph

    s.h("Processing steps")
    rows = [["step", "state", "note"]]
    for st in meta.get("steps", []):
        rows.append([st["name"], st["state"],
                     Paragraph(esc(scrub(st.get("error") or "", s.run_dir)[:300]), s.styles["BodyText"])])
    s.table(rows, widths=[25 * mm, 25 * mm, 120 * mm])


# ------------------------------------------------------------------------------------------------ assembly


def _context(run_dir: Path, meta: dict) -> dict:
    from georef_core.adjustment.accuracy_standard import assess_accuracy

    geo = run_data.read_json(run_dir / "georef_summary.json")
    ctx = {"made": datetime.now(timezone.utc), "gnss": run_data.gnss_summary(run_dir), "georef": geo,
           "lever": run_data.read_json(run_dir / "lever_arm_delay.json"),
           "dense": run_data.read_json(run_dir / "dense" / "dense_summary.json"),
           "design": run_data.read_json(run_dir / "design" / "cut_fill.json"),
           "residuals": run_data.residuals(run_dir), "triggers": run_data.trigger_rows(run_dir),
           "epochs": run_data.pos_epochs(run_dir / "ppk" / "trajectory.pos")}
    tol = (meta.get("tolerance_horizontal_m"), meta.get("tolerance_vertical_m"))
    ctx["tolerance"] = tol
    pts = (ctx["residuals"] or {}).get("points") or []
    ctx["verdict"] = tolerance_verdict([q for q in pts if str(q.get("role") or "check") == "check"], *tol)
    # the check points' own survey accuracy: the run's georef setting, else what the step used, else its default
    sig = ((meta.get("settings") or {}).get("georef") or {}).get("gcp_sigma_m") or \
        ((geo or {}).get("options") or {}).get("gcp_sigma_m") or (0.01, 0.02)
    ctx["check_sigma_m"] = (float(sig[0]), float(sig[1]))
    target = (meta.get("asprs_horizontal_class_cm"), meta.get("asprs_vertical_class_cm"))
    ctx["asprs"] = assess_accuracy(ctx["residuals"]["raw"] if (ctx["residuals"] or {}).get("raw") else
                                   {"points": pts}, ctx["check_sigma_m"],
                                   target if any(v is not None for v in target) else None) if ctx["residuals"] else None
    ctx["glance"] = _glance(meta, ctx)
    return ctx


def _glance(meta: dict, ctx: dict) -> list[tuple[str, tuple | None]]:
    out = []
    gs = ctx["gnss"] or {}
    if finite(gs.get("fix_rate")):
        out.append((f"GNSS: {100 * gs['fix_rate']:.1f} % of the epochs fixed"
                    + (f", {gs['events'].get('fixed', '-')} of {gs['events'].get('count', '-')} camera triggers on fixed "
                       "epochs" if gs.get("events") else "") + ".", GREEN if gs["fix_rate"] >= 0.95 else AMBER))
    v = ctx["verdict"]
    if v.get("set") and v.get("n"):
        th, tv = ctx["tolerance"]
        out.append((f"Check points: {'all ' + str(v['n']) + ' within' if v['pass'] else str(len(v['outside'])) + ' of ' + str(v['n']) + ' outside'}"
                    f" the site tolerance ({cm(th)} horizontal, {cm(tv)} vertical).", GREEN if v["pass"] else RED))
    elif not v.get("set"):
        out.append(("Check points: no tolerance set for this site.", None))
    a = ctx["asprs"]
    if a is not None and a.n_check_points:
        out.append((f"Accuracy: RMSE_H {a.horizontal.product_rmse_cm:.1f} cm, RMSE_V {a.vertical.product_rmse_cm:.1f} cm "
                    f"from {a.n_check_points} check point{'s' if a.n_check_points != 1 else ''}"
                    + ("" if a.compliant else " (no ASPRS compliance statement: fewer than "
                       f"{a.min_check_points} check points or no class met)") + ".", None))
    vols = meta.get("volumes") or []
    if vols:
        out.append((f"Volumes: {len(vols)} stockpile{'s' if len(vols) != 1 else ''} measured (section "
                    "'Stockpile volumes and inventory').", None))
    bad = [st["name"] for st in meta.get("steps") or [] if st.get("state") not in ("succeeded", "reused", "skipped", None)]
    if bad:
        out.append((f"Steps not succeeded: {', '.join(bad)}.", AMBER))
    return out or [("No results in this run yet.", None)]


def build_report(run_dir: Path, out_pdf: Path, meta: dict, survey_dir: Path | None = None) -> dict:
    """Write the PDF; returns a summary of what it contains. `meta`: site, company, crs, vertical_datum, geoid,
    survey, title, flown_at, flown_at_source, run_number, steps [{name, state, error}], settings {step:
    {option: value}}, tolerance_horizontal_m, tolerance_vertical_m, asprs_horizontal_class_cm,
    asprs_vertical_class_cm, volumes [{name, base, volume_m3, sigma_m3, material, density_t_m3}],
    stockpile_outlines [{name, outline}], previous {run_number, volumes {name: m3}, rmse_d_m}. `survey_dir`: the
    survey files the report reads (gcp/points.csv for the map), default the run folder's survey/ beside it."""
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.units import mm
    from reportlab.platypus import BaseDocTemplate, Frame, PageTemplate

    run_dir = Path(run_dir)
    if survey_dir is None and (run_dir.parent / "survey").is_dir():
        survey_dir = run_dir.parent / "survey"
    s = _Story(run_dir)
    ctx = _context(run_dir, meta)
    _cover(s, meta, ctx)
    _equipment(s, ctx)
    _settings(s, meta)
    _gnss(s, ctx)
    _georef(s, ctx)
    _residuals(s, meta, ctx)
    _maps(s, meta, ctx, survey_dir)
    _volumes(s, meta, ctx)
    _steps(s, meta)

    out_pdf = Path(out_pdf)
    out_pdf.parent.mkdir(parents=True, exist_ok=True)
    footer = plain(f"{meta.get('site', '')} · {meta.get('survey', '')} · run {meta.get('run_number', '?')} · "
                   f"Georef {software_version()}")[:150]

    def page_end(canvas, doc):
        canvas.saveState()
        canvas.setFont("Helvetica", 7)
        canvas.setFillGray(0.35)
        canvas.drawString(18 * mm, 10 * mm, footer)
        canvas.drawRightString(A4[0] - 18 * mm, 10 * mm, f"page {doc.page}")
        canvas.restoreState()

    doc = BaseDocTemplate(str(out_pdf), pagesize=A4, title=plain(f"Accuracy report {meta.get('survey', '')}"),
                          author="Georef", subject="", creator="Georef", leftMargin=18 * mm, rightMargin=18 * mm,
                          topMargin=16 * mm, bottomMargin=18 * mm)
    frame = Frame(doc.leftMargin, doc.bottomMargin, doc.width, doc.height, id="body")
    doc.addPageTemplates([PageTemplate(id="page", frames=[frame], onPageEnd=page_end)])
    from reportlab import rl_config

    a85 = rl_config.useA85
    rl_config.useA85 = 0        # binary streams: ASCII85 in pure Python took seconds for the map images
    try:
        doc.build(s.flow)
    finally:
        rl_config.useA85 = a85
    return {"pdf": out_pdf.name, "sections": s.sections,
            "accuracy": ctx["asprs"].to_dict() if ctx["asprs"] is not None else None,
            "tolerance": {k: v for k, v in ctx["verdict"].items() if k != "per_point"}}
