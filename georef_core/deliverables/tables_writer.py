"""Tables of points and quantities as CSV (UTF-8, comma, one header row, units in the column names) and
XLSX (one sheet per table plus an "About" sheet stating the CRS, the vertical datum and the source files).

A text cell that a spreadsheet would run as a formula (starting with = + - @) is written with a leading
apostrophe in CSV and as a plain string in XLSX."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Table:
    name: str                      # sheet name (31 characters at most) and CSV stem
    columns: list[str]
    rows: list[dict] = field(default_factory=list)


def _safe_text(v):
    if isinstance(v, str) and v[:1] in ("=", "+", "-", "@") and not _is_number(v):
        return "'" + v
    return v


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def write_csv(path, table: Table) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(table.columns)
        for r in table.rows:
            w.writerow(["" if r.get(c) is None else _safe_text(r.get(c)) for c in table.columns])
    return path


def write_xlsx(path, tables: list[Table], about: dict[str, str]) -> Path:
    from openpyxl import Workbook
    from openpyxl.styles import Font

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    wb = Workbook()
    ws = wb.active
    ws.title = "About"
    ws.append(["item", "value"])
    for k, v in about.items():
        ws.append([k, str(v)])
    for t in tables:
        s = wb.create_sheet(t.name[:31])
        s.append(t.columns)
        for cell in s[1]:
            cell.font = Font(bold=True)
        for r in t.rows:
            s.append([r.get(c) for c in t.columns])
            for cell in s[s.max_row]:
                if isinstance(cell.value, str):
                    cell.data_type = "s"     # never a formula
        for col in s.columns:
            width = max(len(str(c.value)) if c.value is not None else 0 for c in col)
            s.column_dimensions[col[0].column_letter].width = min(60, max(8, width + 2))
    ws["A1"].font = Font(bold=True)
    ws["B1"].font = Font(bold=True)
    ws.column_dimensions["A"].width = 24
    ws.column_dimensions["B"].width = 80
    wb.save(path)
    return path
