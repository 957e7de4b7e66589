"""The per-survey PDF accuracy report (reportlab), drawn from a run folder: PPK quality, antenna
precision at the camera triggers, lever arm and delay, check-point residual table with statistics,
stockpile volumes and their change against the previous run, and the state of every step.

Everything shown comes from users (site, survey, stockpile and point names) or from the processing
(warnings, step errors): ReportLab's Paragraph reads its text as markup (<img src="..."/> embeds a file
of the server, a stray "<" fails the build), so every piece of text is escaped before it enters one
(`_esc`), and file paths are reduced to file names (`_scrub`): the report never shows the worker's folders."""

from __future__ import annotations

import json
import math
import re
from datetime import datetime, timezone
from pathlib import Path
from xml.sax.saxutils import escape

from . import result_files
from .display import format_flight_time, format_volume, format_volume_pm, material_label

# characters XML 1.0 does not allow (the Paragraph parser is XML-like): replaced, not passed through
_BAD_CHARS = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffe\uffff]")
# an absolute POSIX path (two components at least) or a Windows drive path, not part of a URL or a ratio
_ABS_PATH = re.compile(r"(?<![\w.:/~-])(?:/|[A-Za-z]:\\)(?:[^\s/\\'\"<>|:;,()]+[/\\])+([^\s/\\'\"<>|:;,()]*)")


def _esc(value) -> str:
    """Plain text -> Paragraph markup that shows exactly that text."""
    return escape(_BAD_CHARS.sub("?", "" if value is None else str(value)))


def _scrub(value, run_dir: Path | None = None) -> str:
    """Text from the processing with file paths reduced to file names (relative to the run folder where
    they are inside it)."""
    text = "" if value is None else str(value)
    if run_dir is not None:
        run_dir = Path(run_dir)
        # the worker passes its run folder's out/ (beside survey/): both, then the folder itself
        for base in (run_dir.parent / "survey", run_dir.parent / "out", run_dir / "survey", run_dir / "out", run_dir):
            text = text.replace(str(base) + "/", "")
    return _ABS_PATH.sub(lambda m: m.group(1) or "", text)


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _fmt(v, nd=3, unit=""):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{nd}f}{unit}"


def build_report(run_dir: Path, out_pdf: Path, meta: dict) -> dict:
    """Write the PDF; returns a summary of what it contains. `meta`: site, crs, vertical_datum, survey,
    flown_at, flown_at_source, run_number, steps [{name, state, error}], volumes [{name, base, volume_m3,
    sigma_m3, material}],
    previous {run_number, volumes {name: m3}, rmse_d_m}."""
    from reportlab.lib import colors
    from reportlab.lib.pagesizes import A4
    from reportlab.lib.styles import getSampleStyleSheet
    from reportlab.lib.units import mm
    from reportlab.platypus import Paragraph, SimpleDocTemplate, Spacer, Table, TableStyle

    run_dir = Path(run_dir)
    styles = getSampleStyleSheet()
    story = []
    sections = []

    def h(text):
        story.append(Spacer(1, 4 * mm))
        story.append(Paragraph(_esc(text), styles["Heading2"]))

    def p(text):
        """A paragraph of plain text (escaped here: never markup)."""
        story.append(Paragraph(_esc(text), styles["BodyText"]))

    def cell(value):
        """A table cell: plain strings are drawn as they are (never parsed as markup)."""
        return _BAD_CHARS.sub("?", value) if isinstance(value, str) else value

    def table(rows, widths=None):
        rows = [[cell(v) for v in r] for r in rows]
        t = Table(rows, colWidths=widths, repeatRows=1)
        t.setStyle(TableStyle([("FONT", (0, 0), (-1, 0), "Helvetica-Bold", 8), ("FONT", (0, 1), (-1, -1), "Helvetica", 8),
                               ("GRID", (0, 0), (-1, -1), 0.25, colors.grey),
                               ("BACKGROUND", (0, 0), (-1, 0), colors.Color(0.9, 0.9, 0.9)),
                               ("ALIGN", (1, 1), (-1, -1), "RIGHT")]))
        story.append(t)

    story.append(Paragraph("Accuracy report: " + _esc(meta.get("survey", "survey")), styles["Title"]))
    story.append(Paragraph(
        f"Site <b>{_esc(meta.get('site', ''))}</b>, project CRS {_esc(meta.get('crs', ''))}"
        + (f", vertical datum {_esc(meta['vertical_datum'])}" if meta.get("vertical_datum") else ", ellipsoidal heights")
        + f". Flight: {_esc(format_flight_time(meta.get('flown_at'), meta.get('flown_at_source')))}. Processing run "
        f"{_esc(meta.get('run_number', '?'))}, report made {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC.",
        styles["BodyText"]))

    # --- GNSS
    gs = _read_json(run_dir / "ppk" / "summary.json") or _read_json(run_dir / "ppk" / "trajectory_summary.json")
    h("1. GNSS trajectory (PPK)")
    if gs:
        sections.append("gnss")
        rows = [["epochs", "fixed", "float", "single", "fix rate"],
                [gs.get("epochs", "-"), gs.get("fix", "-"), gs.get("float", "-"), gs.get("single", "-"),
                 _fmt(100 * gs["fix_rate"], 1, " %") if gs.get("fix_rate") is not None else "-"]]
        table(rows)
        ev = gs.get("events") or {}
        if ev:
            p(f"Camera triggers: {ev.get('count', '-')} events, {ev.get('fixed', '-')} on fixed epochs, "
              f"{ev.get('without_solution', 0)} without solution.")
        for w in (gs.get("warnings") or [])[:10]:
            p(f"Note: {_scrub(w, run_dir)}")
    else:
        p("No GNSS solution in this run.")
    ev_csv = run_dir / "ppk" / "events.csv"
    if not ev_csv.exists():
        ev_csv = run_dir / "ppk" / "trajectory_events.csv"
    if ev_csv.exists():
        rows = result_files.parse_csv(ev_csv.read_text())
        sd = [(r.get("sd_x_m"), r.get("sd_y_m"), r.get("sd_z_m")) for r in rows]
        sd = [s for s in sd if None not in s]
        if sd:
            s3 = [math.sqrt(a * a + b * b + c * c) for a, b, c in sd]
            p(f"Antenna position precision at the triggers (1 sigma, 3D): mean {_fmt(1000 * sum(s3) / len(s3), 1)} mm,"
              f" max {_fmt(1000 * max(s3), 1)} mm over {len(s3)} events.")

    # --- lever arm
    la = _read_json(run_dir / "lever_arm_delay.json")
    h("2. Lever arm and trigger delay")
    if la:
        sections.append("lever_arm")
        rows = [["quantity", "value"]]
        for k, v in la.items():
            if isinstance(v, (int, float)):
                rows.append([k, _fmt(float(v), 4)])
            elif isinstance(v, list) and all(isinstance(x, (int, float)) for x in v):
                rows.append([k, ", ".join(_fmt(float(x), 4) for x in v)])
        table(rows)
    else:
        p("Not estimated in this run (georeferencing step not run or unavailable).")

    # --- residuals
    h("3. Check-point residuals")
    rj, rc = run_dir / "residuals.json", run_dir / "residuals.csv"
    rmse_d = None
    if rj.exists() or rc.exists():
        res = result_files.normalise_residuals(rj.read_text() if rj.exists() else None,
                                               rc.read_text() if rc.exists() else None)
        sections.append("residuals")
        rows = [["point", "role", "dE (m)", "dN (m)", "dh (m)", "|d| (m)"]]
        for q in res["points"]:
            rows.append([q.get("name"), q.get("role", ""), _fmt(q.get("dx_m")), _fmt(q.get("dy_m")), _fmt(q.get("dz_m")),
                         _fmt(q.get("d_m"))])
        table(rows)
        st = res["stats"]      # the core's statistics (residual_table.residual_statistics), as the UI shows them
        if st.get("n"):
            rows = [["", "dE", "dN", "dh", "|d|"]]
            for stat, label in (("mean_m", "mean"), ("std_m", "std"), ("rmse_m", "rmse"), ("max_abs_m", "max abs")):
                rows.append([label] + [_fmt((st.get(c) or {}).get(stat)) for c in ("dx", "dy", "dz")]
                            + [_fmt((st.get("3d") or {}).get("max_m" if stat == "max_abs_m" else stat))])
            story.append(Spacer(1, 2 * mm))
            table(rows)
            rmse_d = result_files.rmse_3d_m(res)
    else:
        p("No residual table in this run (georeferencing step not run or unavailable, or no check point).")
    prev = meta.get("previous") or {}
    if rmse_d is not None and prev.get("rmse_d_m") is not None:
        p(f"3D RMSE {_fmt(rmse_d)} m; previous run {prev.get('run_number')}: {_fmt(prev['rmse_d_m'])} m.")

    # --- volumes
    h("4. Stockpile volumes")
    vols = meta.get("volumes") or []
    if vols:
        sections.append("volumes")
        pv = prev.get("volumes") or {}
        rows = [["stockpile", "material", "base", "volume (m3)", "previous (m3)", "change (m3)"]]
        for v in vols:
            # one rule for every volume (display.py, as in the browser): decimals from the uncertainty
            before, sigma = pv.get(v["name"]), v.get("sigma_m3")
            rows.append([v["name"], material_label(v.get("material")), v.get("base", ""),
                         format_volume_pm(v.get("volume_m3"), sigma), format_volume(before, sigma),
                         format_volume(v["volume_m3"] - before, sigma)
                         if (before is not None and v.get("volume_m3") is not None) else "-"])
        table(rows)
    else:
        p("No volumes in this run (no stockpile defined, or the surface step did not run).")

    # --- steps
    h("5. Processing steps")
    rows = [["step", "state", "note"]]
    for s in meta.get("steps", []):
        rows.append([s["name"], s["state"],
                     Paragraph(_esc(_scrub(s.get("error") or "", run_dir)[:300]), styles["BodyText"])])
    table(rows, widths=[25 * mm, 25 * mm, 120 * mm])

    out_pdf = Path(out_pdf)
    out_pdf.parent.mkdir(parents=True, exist_ok=True)
    doc = SimpleDocTemplate(str(out_pdf), pagesize=A4,
                            title=_BAD_CHARS.sub("?", f"Accuracy report {meta.get('survey', '')}"),
                            author="Georef", subject="", creator="Georef", leftMargin=18 * mm, rightMargin=18 * mm)
    doc.build(story)
    return {"pdf": out_pdf.name, "sections": sections}
