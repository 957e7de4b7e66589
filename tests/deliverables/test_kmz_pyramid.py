"""The KMZ super-overlay of an orthophoto larger than the old single capped level allowed for its pixel size:
a synthetic noisy orthophoto (UTM, 6 cm pixels, COG with overviews) written as a regionated pyramid down to
the zoom that resolves it. Checked: the levels (finest = the zoom of its pixel, coarsest = one root tile), the
tile count of every level against an independent footprint computation (shapely, Mercator), the KML valid
XML with every child's LatLonBox the exact quadrant of its parent and every link's Region the linked tile's.
Memory and time at 8000 and 20000 px: bench/kmz_super_overlay.py."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

KML = "{http://www.opengis.net/kml/2.2}"
E0, N0, EPSG, CELL_M, SIZE_PX = 512_003.0, 5_123_007.0, 32633, 0.06, 1100


@pytest.fixture(scope="module")
def ortho(tmp_path_factory):
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.transform import from_origin

    path = tmp_path_factory.mktemp("kmz_pyramid") / "ortho.tif"
    rng = np.random.default_rng(11)
    x = np.arange(SIZE_PX) * CELL_M
    g = 110 + 40 * np.sin(x[None, :] / 3.0) * np.cos(x[:, None] / 5.0) + rng.normal(0, 25, (SIZE_PX, SIZE_PX))
    rgb = np.clip(np.stack([g * 0.9, g, g * 0.7]), 1, 255).astype(np.uint8)
    profile = dict(driver="GTiff", width=SIZE_PX, height=SIZE_PX, count=3, dtype="uint8", crs=f"EPSG:{EPSG}",
                   transform=from_origin(E0, N0, CELL_M, CELL_M), nodata=0, tiled=True, blockxsize=256,
                   blockysize=256)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(rgb)
        ds.build_overviews([2, 4, 8, 16], Resampling.average)
    return path


def _box(el, tag):
    b = el.find(f"{KML}{tag}")
    return tuple(float(b.findtext(f"{KML}{k}")) for k in ("west", "south", "east", "north"))


def _expected_tiles(z: int) -> tuple[set, set]:
    """Tiles of zoom z that the orthophoto's footprint (its outline in Web Mercator) overlaps by at least 2 x 2
    tile pixels (surely drawn), and by anything at all (possibly drawn: a sliver under half a pixel is
    transparent, so the tile may be left out)."""
    from pyproj import Transformer
    from shapely.geometry import Polygon, box

    from georef_core.tiles.mercator import TILE_PX, tile_bounds_m

    side = SIZE_PX * CELL_M
    t = np.linspace(0, 1, 50)
    e = np.r_[E0 + t * side, np.full(50, E0 + side), E0 + side - t * side, np.full(50, E0)]
    n = np.r_[np.full(50, N0), N0 - t * side, np.full(50, N0 - side), N0 - side + t * side]
    mx, my = Transformer.from_crs(EPSG, 3857, always_xy=True).transform(e, n)
    foot = Polygon(np.column_stack([mx, my]))
    w, s, east, north = foot.bounds
    size = tile_bounds_m(z, 0, 0)[2] - tile_bounds_m(z, 0, 0)[0]
    px2 = (size / TILE_PX) ** 2
    origin = 20037508.342789244
    sure, maybe = set(), set()
    for x in range(int((w + origin) // size), int((east + origin) // size) + 1):
        for y in range(int((origin - north) // size), int((origin - s) // size) + 1):
            a = foot.intersection(box(*tile_bounds_m(z, x, y))).area
            if a > 0:
                maybe.add((z, x, y))
            if a >= 4 * px2:
                sure.add((z, x, y))
    return sure, maybe


def test_pyramid_levels_counts_and_nesting(ortho, tmp_path):
    from lxml import etree

    from georef_core.deliverables.kmz_writer import write_kmz
    from georef_core.tiles.render import raster_info

    info = raster_info(ortho, "rgb")
    out = tmp_path / "ortho.kmz"
    k = write_kmz(ortho, out, tile_threshold_px=1024)
    assert k["tiled"]
    # the finest level is the zoom that resolves the 6 cm pixels (no tile cap), the coarsest a single root
    assert k["levels"][-1] == info.max_zoom and k["levels"] == list(range(k["levels"][0], info.max_zoom + 1))
    assert k["pixel_m"] <= CELL_M
    assert k["tiles_per_level"][str(k["levels"][0])] == 1

    with zipfile.ZipFile(out) as z:
        names = z.namelist()
        files = {n: z.read(n) for n in names if n.endswith(".kml")}
    assert names[0] == "doc.kml"
    images = {n for n in names if n.endswith((".jpg", ".png"))}
    by_level: dict[int, set] = {}
    for n in images:
        zz, x, y = (int(v) for v in n.split("/")[1].split(".")[0].split("_"))
        by_level.setdefault(zz, set()).add((zz, x, y))
    assert {str(zz): len(v) for zz, v in by_level.items()} == k["tiles_per_level"]
    # every level's tiles against the footprint computed independently
    for zz in k["levels"]:
        sure, maybe = _expected_tiles(zz)
        assert sure <= by_level[zz] <= maybe, zz
    assert len(by_level[info.max_zoom]) >= 25

    # the KML: valid XML throughout; walk from doc.kml; each link's Region is the linked tile's Region, each
    # child's box one exact quadrant of its parent's (in Mercator y, so in latitude: compare the edges)
    doc = etree.fromstring(files["doc.kml"])
    todo = [("tiles/" + lk.findtext(f"{KML}Link/{KML}href").split("/", 1)[1], _box(lk.find(f"{KML}Region"),
                                                                                      "LatLonAltBox"), None)
            for lk in doc.iter(f"{KML}NetworkLink")]
    assert len(todo) == 1
    seen = set()
    while todo:
        path, link_box, parent = todo.pop()
        t = etree.fromstring(files[path])
        seen.add(path)
        region = _box(t.find(f"{KML}Document/{KML}Region"), "LatLonAltBox")
        assert region == link_box
        lod = t.find(f"{KML}Document/{KML}Region/{KML}Lod")
        assert lod is not None and float(lod.findtext(f"{KML}minLodPixels")) >= 0
        ov = t.find(f"{KML}Document/{KML}GroundOverlay")
        if ov is not None:
            assert _box(ov, "LatLonBox") == region
            assert "tiles/" + ov.findtext(f"{KML}Icon/{KML}href") in images
        if parent is not None:
            pw, ps, pe, pn = parent
            w, s, e, n = region
            mid_lon = (pw + pe) / 2
            assert (w, e) in ((pw, pytest.approx(mid_lon)), (pytest.approx(mid_lon), pe))
            assert (s == ps or n == pn) and ps <= s < n <= pn
        for lk in t.iter(f"{KML}NetworkLink"):
            todo.append(("tiles/" + lk.findtext(f"{KML}Link/{KML}href"),
                         _box(lk.find(f"{KML}Region"), "LatLonAltBox"), region))
    assert seen == set(files) - {"doc.kml"}
    assert {p.replace(".kml", "") for p in seen} >= {i.rsplit(".", 1)[0] for i in images}



def test_no_cap_on_the_finest_level_of_a_large_orthophoto():
    """A 20 000 px orthophoto at 3 cm (600 m): the pyramid goes down to the zoom that resolves it, several
    thousand tiles there (the earlier writer stopped at 1024 and 10 cm pixels), up to one root tile; a cap
    still applies when asked for."""
    from pyproj import Transformer

    from georef_core.deliverables.kmz_writer import overlay_levels, tile_range
    from georef_core.tiles.mercator import ground_pixel_m, zoom_for_pixel

    lon, lat = Transformer.from_crs(EPSG, 4326, always_xy=True).transform([E0, E0 + 600.0], [N0 - 600.0, N0])
    bounds = (lon[0], lat[0], lon[1], lat[1])
    zf = zoom_for_pixel(0.03, (lat[0] + lat[1]) / 2)
    levels = overlay_levels(bounds, zf)
    assert levels[-1] == zf and ground_pixel_m(zf, lat[0]) <= 0.03

    def count(z):
        x0, y0, x1, y1 = tile_range(bounds, z)
        return (x1 - x0 + 1) * (y1 - y0 + 1)

    assert count(levels[-1]) > 4 * 1024 and count(levels[0]) == 1
    assert all(count(z) > 1 for z in levels[1:])
    capped = overlay_levels(bounds, zf, max_tiles=1024)
    assert capped[0] == levels[0] and capped[-1] < zf and count(capped[-1]) <= 1024
