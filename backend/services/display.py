"""How figures, names and times are written, in the PDF report and the API (the browser UI follows the
same rules: frontend/src/lib/format.ts, checked against the same cases, frontend/tests/fixtures/
volume_format_cases.json).

Volumes: as many decimals as the uncertainty supports (its first two significant digits: 15.24 +- 0.13,
1,523 +- 12), at most 3; without an uncertainty, by magnitude (2 decimals below 100 m3, 1 below 10 000,
then none). Thousands separated by commas. Materials: a stored identifier ("crushed_stone") is shown by its
label ("Crushed stone"); a material typed as words is shown as typed."""

from __future__ import annotations

import math
import re
from datetime import datetime, timezone

MATERIAL_LABELS = {"gravel": "Gravel", "sand": "Sand", "crushed_stone": "Crushed stone", "topsoil": "Topsoil",
                   "clay": "Clay", "fill": "Fill", "rock": "Rock", "asphalt": "Asphalt", "concrete": "Concrete"}
_IDENTIFIER = re.compile(r"^[a-z0-9]+(?:[_-][a-z0-9]+)*$")

FLIGHT_TIME_SOURCES = {"user": "given", "gnss": "read from the GNSS solution",
                       "dji-mrk": "read from the DJI MRK exposures", "exif": "read from the photos' EXIF times"}


def iso_time(t: datetime | None) -> str | None:
    """A time as the API writes every time: ISO 8601 with 'T' and the zone, 'Z' for UTC (as the schemas
    write them); a naive time is UTC."""
    if t is None:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    text = t.isoformat()
    return text[:-6] + "Z" if text.endswith("+00:00") else text


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def volume_decimals(m3, sigma_m3=None) -> int:
    if _finite(sigma_m3) and sigma_m3 > 0:
        return max(0, min(3, 1 - math.floor(math.log10(sigma_m3))))
    a = abs(m3) if _finite(m3) else 0.0
    return 2 if a < 100 else 1 if a < 10000 else 0


def format_volume(m3, sigma_m3=None) -> str:
    """'15.24' (no unit); '-' when there is no value."""
    if not _finite(m3):
        return "-"
    return f"{m3:,.{volume_decimals(m3, sigma_m3)}f}"


def format_volume_pm(m3, sigma_m3=None) -> str:
    """'15.24 +- 0.13' (the uncertainty with the value's decimals), or the value alone."""
    text = format_volume(m3, sigma_m3)
    if text != "-" and _finite(sigma_m3) and sigma_m3 > 0:
        return f"{text} ± {sigma_m3:,.{volume_decimals(m3, sigma_m3)}f}"
    return text


def material_label(material: str | None) -> str:
    m = (material or "").strip()
    if not m:
        return ""
    if m.lower() in MATERIAL_LABELS:
        return MATERIAL_LABELS[m.lower()]
    if _IDENTIFIER.match(m):
        words = " ".join(re.split(r"[_-]", m))
        return words[0].upper() + words[1:]
    return m


def format_flight_time(flown_at, source: str | None = None) -> str:
    """'2024-06-24 08:10 UTC (read from the GNSS solution)', or 'date not known' without one."""
    if not flown_at:
        return "date not known (none given, none in the data)"
    t = flown_at
    if isinstance(t, str):
        try:
            t = datetime.fromisoformat(t.replace("Z", "+00:00"))
        except ValueError:
            return t
    if t.tzinfo is None:
        t = t.replace(tzinfo=timezone.utc)
    text = t.astimezone(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    how = FLIGHT_TIME_SOURCES.get(source or "")
    return f"{text} ({how})" if how and source != "user" else text
