"""The survey report's figures: the GNSS fix status over the flight (a ReportLab vector drawing) and the maps
(orthophoto with the surveyed points, DSM hillshade, cut/fill to design), drawn with numpy and Pillow from
decimated reads of the run's rasters (rasterio reads a cloud-optimised GeoTIFF's overviews), embedded as
images the report makes itself: no file named by a user or a summary is ever embedded."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FIX_COLOURS = {1: (0.16, 0.62, 0.28), 2: (0.95, 0.61, 0.07), 5: (0.80, 0.15, 0.15)}
FIX_LABELS = {1: "fixed", 2: "float", 5: "single / other"}


# ------------------------------------------------------------------------------------------- GNSS figure


def fix_status_drawing(t_s: np.ndarray, status: np.ndarray, sigma3d_m: np.ndarray, triggers_s: np.ndarray,
                       width_pt: float, start_label: str = ""):
    """The fix status of every epoch as a coloured band over the flight's time, the camera triggers as ticks
    above it, and the antenna's 3D position sigma (cm, 1 sigma) below: a vector drawing."""
    from reportlab.graphics.shapes import Drawing, Line, PolyLine, Rect, String
    from reportlab.lib import colors

    left, right, band_h, plot_h, gap = 42.0, 8.0, 14.0, 58.0, 8.0
    height = 18 + band_h + gap + plot_h + 26
    d = Drawing(width_pt, height)
    w = width_pt - left - right
    t = np.asarray(t_s, float)
    if t.size == 0:
        return d
    t0, t1 = float(t.min()), float(max(t.max(), t.min() + 1e-6))
    def x(v):
        return left + (np.asarray(v, float) - t0) / (t1 - t0) * w
    band_y = height - 18 - band_h
    # the band: runs of one status as one rectangle each
    st = np.where(np.isin(status, (1, 2)), status, 5).astype(int)
    cuts = np.flatnonzero(np.diff(st)) + 1
    starts = np.r_[0, cuts]
    ends = np.r_[cuts, len(st)]
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    for a, b in zip(starts, ends):
        xa, xb = float(x(t[a] - step / 2)), float(x(t[b - 1] + step / 2))
        xa, xb = max(xa, left), min(xb, left + w)
        d.add(Rect(xa, band_y, max(xb - xa, 0.4), band_h, fillColor=colors.Color(*FIX_COLOURS[int(st[a])]),
                   strokeColor=None))
    d.add(String(left - 4, band_y + 4, "fix", fontName="Helvetica", fontSize=7, textAnchor="end"))
    for tt in np.asarray(triggers_s, float):
        if t0 <= tt <= t1:
            xx = float(x(tt))
            d.add(Line(xx, band_y + band_h, xx, band_y + band_h + 5, strokeColor=colors.black, strokeWidth=0.6))
    d.add(String(left + w, band_y + band_h + 7, "ticks: camera triggers", fontName="Helvetica", fontSize=6.5,
                 textAnchor="end"))
    # legend
    lx = left
    for code in (1, 2, 5):
        d.add(Rect(lx, band_y + band_h + 7, 7, 5, fillColor=colors.Color(*FIX_COLOURS[code]), strokeColor=None))
        d.add(String(lx + 9, band_y + band_h + 7, FIX_LABELS[code], fontName="Helvetica", fontSize=6.5))
        lx += 14 + 4.2 * len(FIX_LABELS[code]) + 6
    # the sigma plot
    py = 26.0
    s_cm = 100.0 * np.asarray(sigma3d_m, float)
    ok = np.isfinite(s_cm)
    top = float(np.nanpercentile(s_cm[ok], 99)) if ok.any() else 1.0
    top = _nice_ceiling(max(top * 1.1, 0.5))
    d.add(Rect(left, py, w, plot_h, fillColor=None, strokeColor=colors.grey, strokeWidth=0.4))
    for frac in (0.0, 0.5, 1.0):
        yy = py + frac * plot_h
        d.add(Line(left - 2, yy, left, yy, strokeColor=colors.grey, strokeWidth=0.4))
        d.add(String(left - 4, yy - 2.5, f"{frac * top:g}", fontName="Helvetica", fontSize=6.5, textAnchor="end"))
    d.add(String(6, py + plot_h / 2 - 3, "cm", fontName="Helvetica", fontSize=7))
    if ok.any():
        # at most ~1500 vertices: the largest sigma of each group (a spike stays visible)
        idx = np.flatnonzero(ok)
        groups = np.array_split(idx, min(len(idx), 1500))
        pts = []
        for g in groups:
            k = g[np.argmax(s_cm[g])]
            pts += [float(x(t[k])), py + min(float(s_cm[k]), top) / top * plot_h]
        d.add(PolyLine(pts, strokeColor=colors.Color(0.1, 0.3, 0.7), strokeWidth=0.7))
    d.add(String(left + 2, py + plot_h - 8, "antenna position sigma (3D, 1 sigma)", fontName="Helvetica", fontSize=6.5))
    # time axis
    span = t1 - t0
    tick = _nice_step(span / 6)
    k0 = math.ceil(0 / tick)
    v = k0 * tick
    while v <= span + 1e-9:
        xx = float(x(t0 + v))
        d.add(Line(xx, py - 2, xx, py, strokeColor=colors.grey, strokeWidth=0.4))
        label = f"{v / 60:g} min" if tick >= 60 else f"{v:g} s"
        d.add(String(xx, py - 10, label, fontName="Helvetica", fontSize=6.5, textAnchor="middle"))
        v += tick
    if start_label:
        d.add(String(left, 4, f"time from {start_label}", fontName="Helvetica", fontSize=6.5))
    return d


def _nice_step(x: float) -> float:
    if not (x > 0):
        return 1.0
    e = 10 ** math.floor(math.log10(x))
    for m in (1, 2, 5, 10):
        if m * e >= x:
            return m * e
    return 10 * e


def _nice_ceiling(x: float) -> float:
    e = 10 ** math.floor(math.log10(x))
    for m in (1, 1.5, 2, 2.5, 3, 4, 5, 6, 8, 10):
        if m * e >= x:
            return m * e
    return 10 * e


# ------------------------------------------------------------------------------------------------- maps


@dataclass
class Grid:
    """A decimated raster: data (bands, rows, cols) and where it lies (x0, y0 of the top-left corner, cell
    sizes dx > 0, dy < 0), in its CRS."""
    data: np.ndarray
    valid: np.ndarray
    x0: float
    y0: float
    dx: float
    dy: float
    crs: str
    full_cell_m: float

    def to_pixel(self, e, n):
        return (np.asarray(e, float) - self.x0) / self.dx, (np.asarray(n, float) - self.y0) / self.dy

    @property
    def width_m(self) -> float:
        return self.data.shape[2] * self.dx

    @property
    def height_m(self) -> float:
        return self.data.shape[1] * -self.dy


def read_grid(path: Path, max_px: int, bands=None) -> Grid | None:
    """The raster read at most max_px on its longer side (average of the cells; rasterio uses the overviews
    of a COG), with its validity mask; None when it cannot be read."""
    try:
        import rasterio
        from rasterio.enums import Resampling
    except ImportError:
        return None
    try:
        with rasterio.open(path) as src:
            scale = max(src.width, src.height) / float(max_px)
            scale = max(scale, 1.0)
            w, h = max(1, int(round(src.width / scale))), max(1, int(round(src.height / scale)))
            idx = list(bands) if bands else list(range(1, src.count + 1))
            data = src.read(idx, out_shape=(len(idx), h, w), resampling=Resampling.average, masked=False).astype(np.float32)
            mask = src.read_masks(1, out_shape=(h, w), resampling=Resampling.nearest) > 0
            if src.nodata is not None and np.isnan(src.nodata):
                mask &= np.isfinite(data[0])
            mask &= np.all(np.isfinite(data), axis=0)
            tr = src.transform
            crs = src.crs.to_string() if src.crs else ""
            return Grid(data, mask, tr.c, tr.f, tr.a * src.width / w, tr.e * src.height / h, crs, abs(tr.a))
    except Exception:           # noqa: BLE001 - an unreadable raster leaves its map out, with a note
        return None


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:           # Pillow < 10.1
        return ImageFont.load_default()


def _scale_bar(draw, img_w: int, img_h: int, m_per_px: float) -> None:
    k = max(1.0, img_w / 600.0)
    target = img_w * m_per_px / 4
    length = _nice_step(target) if target > 0 else 1
    if length > target * 1.5:
        length /= 2
    px = length / m_per_px
    fs = int(round(16 * k))
    x0, y0 = 12 * k, img_h - 16 * k
    draw.rectangle([x0 - 4 * k, y0 - fs - 6 * k, x0 + px + 3.5 * fs, y0 + 6 * k], fill=(255, 255, 255))
    draw.rectangle([x0, y0 - 3 * k, x0 + px, y0 + 2 * k], fill=(0, 0, 0))
    draw.text((x0 + px + 5 * k, y0 - 0.7 * fs), f"{length:g} m", fill=(0, 0, 0), font=_font(fs))
    # north arrow (the grid's north: maps are drawn north up in the project CRS)
    ax, ay = img_w - 20 * k, 8 * k
    draw.polygon([(ax, ay), (ax - 7 * k, ay + 18 * k), (ax + 7 * k, ay + 18 * k)], fill=(0, 0, 0))
    draw.text((ax - 0.35 * fs, ay + 20 * k), "N", fill=(0, 0, 0), font=_font(fs))


def _enlarged(img, min_px: int = 700):
    """A small picture enlarged by a whole factor (cells stay crisp) so that markers, names and the scale bar
    keep their size on the page; returns it and the factor."""
    from PIL import Image

    f = max(1, math.ceil(min_px / max(img.width, 1)))
    return (img.resize((img.width * f, img.height * f), Image.NEAREST) if f > 1 else img), f


def _png(img, fmt: str = "PNG") -> bytes:
    buf = io.BytesIO()
    if fmt == "JPEG":
        img.convert("RGB").save(buf, "JPEG", quality=82, optimize=True)
    else:
        img.save(buf, "PNG")
    return buf.getvalue()


def ortho_map(grid: Grid, points: list[dict], outlines: list[dict] | None = None) -> bytes:
    """The orthophoto, north up, with the surveyed points (check: circle, control: triangle, each named) and
    the stockpile outlines; JPEG bytes."""
    from PIL import Image, ImageDraw

    rgb = grid.data[:3] if grid.data.shape[0] >= 3 else np.repeat(grid.data[:1], 3, axis=0)
    hi = float(np.nanpercentile(rgb[:, grid.valid], 99.5)) if grid.valid.any() else 255.0
    scale = 255.0 / hi if hi > 255.0 * 1.05 or hi < 64 else 1.0      # 16-bit or dark images stretched
    arr = np.clip(np.moveaxis(rgb, 0, -1) * scale, 0, 255).astype(np.uint8)
    arr[~grid.valid] = 255
    img, up = _enlarged(Image.fromarray(arr, "RGB"))
    draw = ImageDraw.Draw(img)
    _outlines(draw, grid, outlines, (255, 220, 0), up)
    k = max(1.0, img.width / 700.0)            # markers and names in proportion to the picture
    f = _font(int(round(14 * k)))
    for p in points:
        c, r = grid.to_pixel(p["e"], p["n"])
        c, r = float(c) * up, float(r) * up
        if not (-20 <= c <= img.width + 20 and -20 <= r <= img.height + 20):
            continue
        col = (220, 30, 30) if p.get("role") == "check" else (30, 90, 230)
        a, w = 8 * k, int(round(3 * k))
        if p.get("role") == "check":
            draw.ellipse([c - a, r - a, c + a, r + a], outline=col, width=w)
        else:
            draw.polygon([(c, r - 1.2 * a), (c - a, r + 0.75 * a), (c + a, r + 0.75 * a)], outline=col, width=w)
        draw.text((c + 1.3 * a, r - a), str(p["name"])[:24], fill=col, font=f, stroke_width=w,
                  stroke_fill=(255, 255, 255))
    _scale_bar(draw, img.width, img.height, grid.dx / up)
    return _png(img, "JPEG")


def _outlines(draw, grid: Grid, outlines, colour, up: int = 1) -> None:
    for o in outlines or []:
        ring = o.get("ring")
        if ring is None or len(ring) < 3:
            continue
        c, r = grid.to_pixel([q[0] for q in ring], [q[1] for q in ring])
        c, r = c * up, r * up
        draw.line(list(zip(c.tolist(), r.tolist())) + [(float(c[0]), float(r[0]))], fill=colour, width=2)


HYPSO = np.array([[0.0, 38, 115, 77], [0.25, 120, 170, 80], [0.5, 230, 220, 140], [0.75, 190, 140, 90],
                  [1.0, 245, 245, 245]], dtype=float)


def hillshade_map(grid: Grid, outlines: list[dict] | None = None) -> tuple[bytes, float, float]:
    """The DSM coloured by height over its hillshade (sun from the north-west, 45 degrees up), north up; PNG
    bytes and the height range (m) of the colour ramp (2nd and 98th percentiles)."""
    from PIL import Image, ImageDraw

    z = grid.data[0].astype(float)
    v = grid.valid
    zf = np.where(v, z, np.nanmedian(z[v]) if v.any() else 0.0)
    gy, gx = np.gradient(zf, -grid.dy, grid.dx)       # rows go south: d/dy(north) = -d/drow
    gy = -gy
    az, alt = math.radians(315.0), math.radians(45.0)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, -gy)          # the downslope direction, clockwise from north
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    shade = np.clip(shade, 0, 1)
    lo, hi = (float(np.percentile(z[v], 2)), float(np.percentile(z[v], 98))) if v.any() else (0.0, 1.0)
    if hi <= lo:
        hi = lo + 1.0
    u = np.clip((zf - lo) / (hi - lo), 0, 1)
    rgb = np.stack([np.interp(u, HYPSO[:, 0], HYPSO[:, k]) for k in (1, 2, 3)], axis=-1)
    rgb = rgb * (0.35 + 0.65 * shade[..., None])
    rgb[~v] = 255
    img, up = _enlarged(Image.fromarray(np.clip(rgb, 0, 255).astype(np.uint8), "RGB"))
    draw = ImageDraw.Draw(img)
    _outlines(draw, grid, outlines, (20, 20, 20), up)
    _scale_bar(draw, img.width, img.height, grid.dx / up)
    return _png(img), lo, hi


CUT_FILL_COLOURS = {"fill, more than 2 x the tolerance below design": (33, 102, 172),
                    "fill, 1 to 2 x the tolerance below design": (146, 197, 222),
                    "on grade, within the tolerance": (215, 215, 215),
                    "cut, 1 to 2 x the tolerance above design": (244, 165, 130),
                    "cut, more than 2 x the tolerance above design": (178, 24, 43)}


def cut_fill_map(grid: Grid, tolerance_m: float) -> bytes:
    """Surveyed minus design, in five classes around the tolerance (blue: below design, fill; red: above,
    cut), north up; PNG bytes."""
    from PIL import Image, ImageDraw

    d = grid.data[0].astype(float)
    t = tolerance_m if tolerance_m and tolerance_m > 0 else 0.05
    cols = list(CUT_FILL_COLOURS.values())
    cls = np.digitize(d, [-2 * t, -t, t, 2 * t])
    # classes: 0 fill beyond 2t, 1 fill t..2t, 2 on grade, 3 cut t..2t, 4 cut beyond 2t (CUT_FILL_COLOURS' order)
    palette = np.array(cols, dtype=np.uint8)
    rgb = palette[np.clip(cls, 0, 4)]
    rgb[~grid.valid] = 255
    img, up = _enlarged(Image.fromarray(rgb, "RGB"))
    _scale_bar(ImageDraw.Draw(img), img.width, img.height, grid.dx / up)
    return _png(img)
