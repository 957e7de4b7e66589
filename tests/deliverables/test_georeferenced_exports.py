"""The CRS inside the DXF (the model space's GEODATA object, read back with ezdxf) and the KMZ super-overlay of
a large orthophoto (forced here on the small scene of conftest.py by a low tile threshold): its KML tree walked
from doc.kml, every tile decoded and placed inside its parent, the finest tiles covering the orthophoto, and
the whole read back by GDAL's KML super-overlay driver with the orthophoto's colours where they fall."""

from __future__ import annotations

import io
import zipfile

import numpy as np

from georef_core.deliverables.exports import export_run

from . import conftest as C

KML = "{http://www.opengis.net/kml/2.2}"


def test_dxf_states_its_crs_in_geodata_and_prj(run_folder, tmp_path):
    import ezdxf
    from lxml import etree
    from pyproj import CRS, Transformer

    run, survey = run_folder
    export_run(run, formats=["dxf"], survey_dir=survey, interval_m=1.0)
    out = run / "exports"
    doc = ezdxf.readfile(out / "site.dxf")
    assert doc.header["$INSUNITS"] == 6                                  # metres
    geo = doc.modelspace().get_geodata()
    assert geo is not None
    assert geo.get_crs() == (32632, True)                                # EPSG code, easting first
    assert geo.decoded_units() == ("m", "m") and geo.dxf.horizontal_unit_scale == 1.0
    # drawing coordinates -> CRS coordinates through the GEODATA transformation, then to lon/lat: the
    # surveyed points land where the survey put them
    matrix, epsg = geo.get_crs_transformation()
    to_ll = Transformer.from_crs(epsg, 4326, always_xy=True)
    truth_ll = Transformer.from_crs(C.EPSG, 4326, always_xy=True)
    labels = {t.dxf.text: t for t in doc.modelspace().query('TEXT[layer=="POINT_LABELS"]')}
    pts = list(doc.modelspace().query("POINT"))
    assert len(pts) == len(C.POINTS) == len(labels)
    for name, _role, e, n in C.POINTS:
        p = min(pts, key=lambda q: (q.dxf.location.x - labels[name].dxf.insert.x) ** 2
                + (q.dxf.location.y - labels[name].dxf.insert.y) ** 2)   # the point its label stands beside
        x, y, _ = matrix.transform(p.dxf.location)
        lon, lat = to_ll.transform(x, y)
        lon0, lat0 = truth_ll.transform(e, n)
        assert abs(lon - lon0) < 1e-8 and abs(lat - lat0) < 1e-8, name   # < 1 mm
    # the design point sits inside the drawing (the scene is 60 m across)
    dp = geo.dxf.design_point
    assert C.X0 <= dp.x <= C.X0 + 60 and C.Y0 - 60 <= dp.y <= C.Y0
    # the definition: datum and ellipsoid with their EPSG codes, the projection's parameters
    xml = etree.fromstring(geo.coordinate_system_definition.replace('encoding="UTF-16" ', "").encode())
    aliases = {(a.get("type"), a.get("id")) for a in xml.iter("{*}Alias")}
    assert {("CoordinateSystem", "32632"), ("Datum", "6326"), ("Ellipsoid", "7030")} <= aliases
    params = {p.findtext("{*}OperationParameterId"): float(p.findtext("{*}Value"))
              for p in xml.iter("{*}ParameterValue")}
    assert params["Longitude of natural origin"] == 9.0 and params["False easting"] == 500000.0
    assert CRS.from_wkt((out / "site.prj").read_text()).to_epsg() == 32632

    # a site CRS without an EPSG code: the projection is described, no EPSG alias is invented
    from georef_core.deliverables.dxf_writer import DxfPolyline, write_dxf

    local = CRS.from_proj4("+proj=tmerc +lat_0=0 +lon_0=9.1234 +k=1 +x_0=20000 +y_0=-4000000 +ellps=GRS80 "
                           "+units=m +no_defs")
    files = write_dxf(tmp_path / "local.dxf", [DxfPolyline("CONTOUR_MINOR", np.array([[0.0, 0.0], [10.0, 5.0]]))],
                      crs=local)
    geo2 = ezdxf.readfile(files[0]).modelspace().get_geodata()
    text = geo2.coordinate_system_definition
    assert "9.1234" in text and "20000" in text and 'type="CoordinateSystem"' not in text
    assert files[1].suffix == ".prj" and "9.1234" in files[1].read_text()


def _box(el, tag):
    b = el.find(f"{KML}{tag}")
    return tuple(float(b.findtext(f"{KML}{k}")) for k in ("west", "south", "east", "north"))


def test_large_orthophoto_becomes_a_super_overlay(run_folder):
    from lxml import etree
    from PIL import Image
    from pyproj import Transformer

    from georef_core.tiles.mercator import TILE_PX

    run, _ = run_folder
    m = export_run(run, formats=["kmz"], kmz_tile_threshold_px=128)     # the 300 px orthophoto, forced to tile
    k = m["kmz"]
    assert k["tiled"] and len(k["levels"]) >= 2 and k["tiles"] == sum(k["tiles_per_level"].values())
    with zipfile.ZipFile(run / "exports" / "ortho.kmz") as z:
        names = z.namelist()
        files = {n: z.read(n) for n in names}
    assert names[0] == "doc.kml" and "files/ortho.png" not in names
    doc = etree.fromstring(files["doc.kml"])
    # walk the tree from doc.kml: every link resolves, every tile has a Region, an overlay image and children
    # of the next level inside it
    # (hrefs are relative to the file that holds them: doc.kml at the root, the tiles in tiles/)
    todo = [(lk.findtext(f"{KML}Link/{KML}href"), None) for lk in doc.iter(f"{KML}NetworkLink")]
    assert todo and all(lk.find(f"{KML}Region") is not None for lk in doc.iter(f"{KML}NetworkLink"))
    seen, finest = set(), {}
    while todo:
        path, parent_box = todo.pop()
        assert path in files, path
        seen.add(path)
        t = etree.fromstring(files[path])
        region = _box(t.find(f"{KML}Document/{KML}Region"), "LatLonAltBox")
        ov = t.find(f"{KML}Document/{KML}GroundOverlay")
        img = None
        if ov is not None:                  # (a tile all no-data above finer tiles with data has none)
            assert _box(ov, "LatLonBox") == region
            img_path = "tiles/" + ov.findtext(f"{KML}Icon/{KML}href")
            img = Image.open(io.BytesIO(files[img_path]))
            assert img.size == (TILE_PX, TILE_PX)
            seen.add(img_path)
        else:
            assert t.find(f"{KML}Document/{KML}NetworkLink") is not None
        if parent_box is not None:
            w, s, e, n = region
            pw, ps, pe, pn = parent_box
            assert pw - 1e-9 <= w < e <= pe + 1e-9 and ps - 1e-9 <= s < n <= pn + 1e-9
        z = int(path.split("/")[1].split("_")[0])
        if z == k["levels"][-1]:
            assert img is not None
            finest[path] = (region, img)
        for lk in t.iter(f"{KML}NetworkLink"):
            assert lk.find(f"{KML}Region/{KML}Lod/{KML}minLodPixels") is not None
            todo.append(("tiles/" + lk.findtext(f"{KML}Link/{KML}href"), region))
    assert seen == set(names) - {"doc.kml"}                             # nothing unreachable
    assert len(finest) == k["tiles_per_level"][str(k["levels"][-1])]

    # the finest tiles cover the orthophoto: every corner and the centre fall in one of them
    to_ll = Transformer.from_crs(C.EPSG, 4326, always_xy=True)
    for e, n in ((C.X0 + 0.1, C.Y0 - 0.1), (C.X0 + 59.9, C.Y0 - 0.1), (C.X0 + 0.1, C.Y0 - 59.9),
                 (C.X0 + 59.9, C.Y0 - 59.9), (C.X0 + 30, C.Y0 - 30)):
        lon, lat = to_ll.transform(e, n)
        assert any(b[0] <= lon <= b[2] and b[1] <= lat <= b[3] for b, _ in finest.values()), (e, n)

    # read back by an independent reader, GDAL's KML super-overlay driver (through rasterio): one raster in
    # WGS 84 that holds the orthophoto's colours where they fall. The orthophoto's red ramps with easting,
    # green with southing (conftest.write_ortho); its northern 4 m are no-data (transparent)
    import rasterio

    with rasterio.open(run / "exports" / "ortho.kmz") as ds:
        assert ds.driver == "KMLSUPEROVERLAY" and ds.crs.to_epsg() == 4326 and ds.count == 4
        w, s, e, n = ds.bounds
        lon, lat = to_ll.transform([C.X0, C.X0 + 60], [C.Y0, C.Y0 - 60])
        assert w <= min(lon) and e >= max(lon) and s <= min(lat) and n >= max(lat)
        rgba = ds.read()
        ee, nn = np.meshgrid(C.X0 + np.arange(1.1, 59.0, 2.3), C.Y0 - np.arange(1.1, 59.0, 2.3))
        lon, lat = to_ll.transform(ee.ravel(), nn.ravel())
        rows, cols = rasterio.transform.rowcol(ds.transform, lon, lat)
    px = rgba[:, rows, cols].astype(float)                              # (4, points)
    col, row = (ee.ravel() - C.X0) / 0.2 - 0.5, (C.Y0 - nn.ravel()) / 0.2 - 0.5
    ok, nodata = row > 22, row < 18
    assert (px[3, ok] == 255).all() and (px[3, nodata] == 0).all() and nodata.sum() >= 10
    assert np.abs(px[0, ok] - 255 * col[ok] / 299).max() < 10
    assert np.abs(px[1, ok] - 255 * row[ok] / 299).max() < 10
    assert np.abs(px[2, ok] - 128).max() < 10

    # a small orthophoto stays one image
    m1 = export_run(run, formats=["kmz"])
    assert not m1["kmz"]["tiled"]
    with zipfile.ZipFile(run / "exports" / "ortho.kmz") as z:
        assert "files/ortho.png" in z.namelist()
