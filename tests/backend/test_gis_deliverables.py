"""Web map tiles of a run (GET /runs/{id}/tiles/..., WMTS): on PostgreSQL, a run whose dense outputs are
synthetic cloud-optimised GeoTIFFs stored as the dense step stores them. A tile's pixels are compared with
the orthophoto's at the same ground point (a marker square at known coordinates and colour gradients of
known slope); access (401, 404 for another organisation, tile tokens only on tile routes), bad tile
numbers, bounded reads at every zoom; and GDAL, QGIS's reader, opens the WMTS endpoint with a tile token
in the URL (gdalinfo, gdal_translate: a real uvicorn on a loopback port)."""

from __future__ import annotations

import io
import os
import shutil
import socket
import subprocess
import time

import numpy as np
import pytest

from .platform_helpers import Api, add_user

CRS = "EPSG:32653"
X0, Y0, CELL, N = 679400.0, 3889300.0, 0.05, 1024          # 51.2 m square, 5 cm cells
MARK = (400, 440, 600, 640)                                 # rows, cols of a blue marker square


def _ortho(path):
    import rasterio
    from rasterio.transform import from_origin

    rows, cols = np.mgrid[0:N, 0:N]
    rgb = np.stack([cols // 4, rows // 4, np.zeros_like(cols)]).astype("uint8")   # 1 DN per 20 cm
    rgb[2, MARK[0]:MARK[1], MARK[2]:MARK[3]] = 255
    with rasterio.open(path, "w", driver="COG", width=N, height=N, count=3, dtype="uint8", crs=CRS,
                       transform=from_origin(X0, Y0, CELL, CELL), blocksize=256) as ds:
        ds.write(rgb)


def _dsm(path):
    import rasterio
    from rasterio.transform import from_origin

    rows, cols = np.mgrid[0:N, 0:N]
    h = 80 + 6 * np.exp(-((cols - 512) ** 2 + (rows - 512) ** 2) / (2 * 150.0 ** 2))
    with rasterio.open(path, "w", driver="COG", width=N, height=N, count=1, dtype="float32", nodata=-9999, crs=CRS,
                       transform=from_origin(X0, Y0, CELL, CELL), blocksize=256) as ds:
        ds.write(h.astype("float32")[None])


@pytest.fixture(scope="module")
def tiled(pg_platform, tmp_path_factory):
    from backend.models import Run, RunOutput

    p = pg_platform
    add_user(p, "tiles-a@example.org", org_admin=True)
    add_user(p, "tiles-b@example.org", org_admin=True)          # another organisation
    a, b = Api(p, "tiles-a@example.org"), Api(p, "tiles-b@example.org")
    site = a.post("/api/v1/sites", json={"name": "Tiles", "crs": CRS}).json()
    survey = a.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F1"}).json()
    tmp = tmp_path_factory.mktemp("tiles")
    _ortho(tmp / "ortho.tif")
    _dsm(tmp / "dsm.tif")
    with p.db().session() as s:
        r = Run(survey_id=survey["id"], site_id=site["id"], number=1, state="succeeded", steps=["dense"])
        s.add(r)
        s.flush()
        run = {"id": r.id}
        for name, path in (("ortho", "dense/ortho.tif"), ("dsm", "dense/dsm.tif")):
            data = (tmp / f"{name}.tif").read_bytes()
            sha, size = p.app.state.storage.put_blob_bytes(data)
            s.add(RunOutput(run_id=run["id"], step_name="dense", path=path, sha256=sha, size=size))
    tile_token = a.post("/api/v1/tokens/tile", json={"name": "qgis", "expires_in_days": 7})
    assert tile_token.status_code == 201, tile_token.text
    read_token = a.post("/api/v1/tokens", json={"name": "gis", "scopes": ["read"]}).json()["token"]
    return {"p": p, "a": a, "b": b, "run": run["id"], "site": site["id"], "tile_token": tile_token.json(),
            "read_token": read_token}


def _lonlat(e, n):
    from pyproj import Transformer

    return Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(e, n)


def _tile_of(e, n, z):
    from georef_core.tiles.mercator import lonlat_to_tile

    fx, fy = lonlat_to_tile(*_lonlat(e, n), z)
    return int(fx), int(fy), int((fx % 1) * 256), int((fy % 1) * 256)


def _png(body: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(body)).convert("RGBA"))


def _cell_centre(row, col):
    return X0 + (col + 0.5) * CELL, Y0 - (row + 0.5) * CELL


def test_tile_pixels_are_the_orthophoto_pixels(tiled):
    a, run = tiled["a"], tiled["run"]
    layers = a.get(f"/api/v1/runs/{run}/tiles").json()["layers"]
    assert {lyr["name"]: lyr["style"] for lyr in layers} == {"ortho": "rgb", "dsm": "heights"}
    ortho = next(lyr for lyr in layers if lyr["name"] == "ortho")
    assert ortho["max_zoom"] == 22          # 5 cm cells at 35 N: z22 pixels are 3.1 cm
    for z in (21, 22):
        # the marker's centre is blue; 0.5 m outside it is not
        mr, mc = (MARK[0] + MARK[1]) / 2, (MARK[2] + MARK[3]) / 2
        e, n = _cell_centre(mr - 0.5, mc - 0.5)
        x, y, px, py = _tile_of(e, n, z)
        r = a.get(f"/api/v1/runs/{run}/tiles/ortho/{z}/{x}/{y}.png")
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        img = _png(r.content)
        assert img[py, px, 2] == 255 and img[py, px, 3] == 255, (z, img[py, px])
        # the gradients: red = column // 4, green = row // 4 at any point of the tile (+-2 DN: 40 cm)
        checked = 0
        for dr, dc in ((-60, -60), (-60, 70), (70, -60), (70, 70)):
            e2, n2 = _cell_centre(mr + dr, mc + dc)
            x2, y2, px2, py2 = _tile_of(e2, n2, z)
            if (x2, y2) != (x, y):
                continue
            want = ((mc + dc) // 4, (mr + dr) // 4)
            got = img[py2, px2, :2].astype(int)
            assert abs(got[0] - want[0]) <= 2 and abs(got[1] - want[1]) <= 2, (z, got, want)
            assert img[py2, px2, 2] == 0
            checked += 1
        assert checked >= 1
    # outside the raster: a transparent tile; a coarse zoom reads an overview (bounded) and is still right
    x, y, _, _ = _tile_of(X0 - 500, Y0 + 500, 18)
    img = _png(a.get(f"/api/v1/runs/{run}/tiles/ortho/18/{x}/{y}.png").content)
    assert img[..., 3].max() == 0


def test_dsm_tiles_and_legend(tiled):
    a, run = tiled["a"], tiled["run"]
    leg = a.get(f"/api/v1/runs/{run}/tiles/dsm/legend.json").json()
    assert leg["units"] == "m" and 79.9 < leg["low"] < 80.5 and 84.0 < leg["high"] < 86.1
    assert len(leg["stops"]) >= 2 and leg["stops"][0]["value"] == pytest.approx(leg["low"], abs=1e-3)
    e, n = _cell_centre(512, 512)
    x, y, px, py = _tile_of(e, n, 19)
    img = _png(a.get(f"/api/v1/runs/{run}/tiles/dsm/19/{x}/{y}.png").content)
    top = leg["stops"][-1]["color"]
    want = np.array([int(top[i:i + 2], 16) for i in (1, 3, 5)])
    # the summit (flat: full light x cos(45) shade) has the ramp's top colour, shaded
    assert img[py, px, 3] == 255
    ratio = img[py, px, :3] / np.maximum(want, 1)
    assert np.all(ratio[want > 30] > 0.6) and np.all(ratio[want > 30] < 1.05), (img[py, px], want)


def test_etag_cache_and_bounded_work(tiled):
    from georef_core.tiles import render

    a, run, p = tiled["a"], tiled["run"], tiled["p"]
    e, n = _cell_centre(500, 500)
    x, y, _, _ = _tile_of(e, n, 20)
    url = f"/api/v1/runs/{run}/tiles/ortho/20/{x}/{y}.png"
    r1 = a.get(url)
    assert r1.status_code == 200 and "immutable" in r1.headers["cache-control"]
    assert r1.headers["etag"].startswith('"') and not r1.headers["etag"].startswith("W/")
    assert a.get(url, headers={"If-None-Match": r1.headers["etag"]}).status_code == 304
    assert a.get(url).content == r1.content
    cached = list((p.settings.resolved_work_dir() / "tiles").rglob("20/*/*.png"))
    assert cached, "tiles are cached on disk"
    # every zoom reads a bounded window: at most 362 cells across (power-of-two overviews) + rotation margin
    from backend.models import RunOutput
    from backend.storage import blob_key

    with p.db().session() as s:
        sha = s.query(RunOutput).filter_by(run_id=run, path="dense/ortho.tif").one().sha256
    src = p.app.state.storage.local_path(blob_key(sha))
    info = render.raster_info(src, "rgb")
    for z in (0, 8, 14, 17, 19, 22, 24):
        x, y, _, _ = _tile_of(e, n, z)
        t = render.render_tile(src, info, z, x, y)
        assert t.png is not None
        assert max(t.read_shape) <= 400, (z, t.read_shape, t.overview_factor)


def test_bad_tiles_and_access(tiled):
    a, b, run = tiled["a"], tiled["b"], tiled["run"]
    anon = tiled["p"].client()
    ok = f"/api/v1/runs/{run}/tiles/ortho/0/0/0.png"
    assert anon.get(ok).status_code == 401
    assert b.get(ok).status_code == 404                                    # another organisation's run
    assert "run not found" in b.get(ok).json()["detail"]
    for bad in ("25/0/0", "3/8/0", "3/0/8", "1/2/1", "99999999999999999999/0/0"):
        r = a.get(f"/api/v1/runs/{run}/tiles/ortho/{bad}.png")
        assert r.status_code == 400, (bad, r.status_code)
    assert a.get(f"/api/v1/runs/{run}/tiles/ortho/-1/0/0.png").status_code in (400, 404, 422)
    assert a.get(f"/api/v1/runs/{run}/tiles/difference/0/0/0.png").status_code == 404   # not in this run
    tok, read = tiled["tile_token"]["token"], tiled["read_token"]
    assert tiled["tile_token"]["scopes"] == ["tiles"] and tiled["tile_token"]["expires_at"]
    # a tile token: tiles in the URL or the header; nothing else, anywhere
    assert anon.get(ok + f"?token={tok}").status_code == 200
    assert anon.get(ok, headers={"Authorization": f"Bearer {tok}"}).status_code == 200
    assert anon.get(f"/api/v1/runs/{run}?token={tok}").status_code == 401
    r = anon.get(f"/api/v1/runs/{run}", headers={"Authorization": f"Bearer {tok}"})
    assert r.status_code == 403 and "tile token" in r.json()["detail"]
    assert anon.get("/api/v1/sites", headers={"Authorization": f"Bearer {tok}"}).status_code == 403
    assert anon.get(f"/api/v1/runs/{run}/results/ortho", headers={"Authorization": f"Bearer {tok}"}).status_code == 403
    # a full API token is never taken from a URL (it would end up in logs); in the header it reads tiles
    assert anon.get(ok + f"?token={read}").status_code == 401
    assert anon.get(ok, headers={"Authorization": f"Bearer {read}"}).status_code == 200
    # an outsider's tile token does not open this run
    btok = b.post("/api/v1/tokens/tile", json={}).json()["token"]
    assert anon.get(ok + f"?token={btok}").status_code == 404
    # tile tokens always expire, and cannot mint tokens
    assert a.post("/api/v1/tokens/tile", json={"expires_in_days": 365}).status_code == 422
    assert anon.post("/api/v1/tokens/tile", json={}, headers={"Authorization": f"Bearer {tok}"}).status_code == 403
    # revoked: refused
    a.delete(f"/api/v1/tokens/{tiled['tile_token']['id']}")
    assert anon.get(ok + f"?token={tok}").status_code == 401


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.skipif(shutil.which("gdalinfo") is None,
                    reason="gdalinfo (Debian gdal-bin; scripts/install_system_deps.sh installs it) is not installed")
def test_gdal_reads_the_wmts_endpoint_with_a_tile_token(tiled, tmp_path):
    import rasterio

    p, a, run = tiled["p"], tiled["a"], tiled["run"]
    tok = a.post("/api/v1/tokens/tile", json={"name": "gdal"}).json()["token"]
    import threading

    import uvicorn

    # the API itself (this platform's app) served over HTTP on a loopback port, in this process
    port = _free_port()
    server = uvicorn.Server(uvicorn.Config(p.app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        base = f"http://127.0.0.1:{port}/api/v1"
        deadline = time.monotonic() + 30
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        assert server.started
        env = {**os.environ, "GDAL_HTTP_TIMEOUT": "30", "CPL_DEBUG": "OFF", "GDAL_DEFAULT_WMS_CACHE_PATH":
               str(tmp_path / "gdalwmscache")}
        src = f"WMTS:{base}/runs/{run}/wmts/1.0.0/WMTSCapabilities.xml?token={tok},layer=ortho"
        info = subprocess.run(["gdalinfo", src], capture_output=True, text=True, env=env, timeout=60)
        assert info.returncode == 0, info.stderr
        out = info.stdout
        assert "Pseudo-Mercator" in out or 'ID["EPSG",3857]' in out, out[:1500]
        assert out.count("Band ") >= 3 and "ColorInterp=Red" in out.replace(" ", ""), out
        # the size: the raster's Mercator extent at zoom 22
        from georef_core.tiles.mercator import tile_size_m
        from georef_core.tiles.render import raster_info

        with rasterio.open(tmp_path / "o.tif", "w", driver="GTiff", width=1, height=1, count=1, dtype="uint8",
                           crs=CRS, transform=rasterio.transform.from_origin(X0, Y0, CELL * N, CELL * N)) as ds:
            ds.write(np.zeros((1, 1, 1), "uint8"))
        mb = raster_info(tmp_path / "o.tif", "rgb").mercator_bounds
        res = tile_size_m(22) / 256
        size = [int(v) for v in out.split("Size is ")[1].split("\n")[0].split(",")]
        assert abs(size[0] - (mb[2] - mb[0]) / res) <= 2 and abs(size[1] - (mb[3] - mb[1]) / res) <= 2, size
        # pixels: a 4 x 4 m window around the marker, read through the tiles, has the marker's blue in its middle
        mr, mc = (MARK[0] + MARK[1]) / 2, (MARK[2] + MARK[3]) / 2
        e, n = _cell_centre(mr - 0.5, mc - 0.5)
        from pyproj import Transformer

        mx, my = Transformer.from_crs(CRS, "EPSG:3857", always_xy=True).transform(e, n)
        out_tif = tmp_path / "win.tif"
        tr = subprocess.run(["gdal_translate", "-q", "-projwin", str(mx - 2), str(my + 2), str(mx + 2), str(my - 2),
                             src, str(out_tif)], capture_output=True, text=True, env=env, timeout=60)
        assert tr.returncode == 0, tr.stderr
        with rasterio.open(out_tif) as ds:
            px = ds.read()
        h, w = px.shape[1:]
        centre = px[:, h // 2, w // 2]
        assert centre[2] == 255 and abs(int(centre[0]) - mc // 4) <= 2 and abs(int(centre[1]) - mr // 4) <= 2, centre
        # the same tiles without a token: GDAL is refused
        bad = subprocess.run(["gdalinfo", f"WMTS:{base}/runs/{run}/wmts/1.0.0/WMTSCapabilities.xml,layer=ortho"],
                             capture_output=True, text=True, env=env, timeout=60)
        assert bad.returncode != 0
    finally:
        server.should_exit = True
        thread.join(timeout=20)


def test_wmts_document_lists_the_layers(tiled):
    import xml.etree.ElementTree as ET

    a, run = tiled["a"], tiled["run"]
    r = a.get(f"/api/v1/runs/{run}/wmts/1.0.0/WMTSCapabilities.xml")
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/xml")
    root = ET.fromstring(r.content)
    ns = {"w": "http://www.opengis.net/wmts/1.0", "ows": "http://www.opengis.net/ows/1.1"}
    names = sorted(x.text for x in root.findall("w:Contents/w:Layer/ows:Identifier", ns))
    assert names == ["dsm", "ortho"]
    tpl = root.find("w:Contents/w:Layer/w:ResourceURL", ns).get("template")
    assert "{TileMatrix}/{TileCol}/{TileRow}.png" in tpl and "token=" not in tpl


# ------------------------------------------------------------------------------------------- inventory


def test_site_inventory_from_stored_volumes(tiled):
    """Two surveys of two piles (one with a density, one of a material with a default, a third never
    measured) as the volumes step stores them; the inventory at dates between and after them."""
    from datetime import datetime

    from openpyxl import load_workbook

    from backend.models import Run, Survey, VolumeMeasurement

    p, a, b, site = tiled["p"], tiled["a"], tiled["b"], tiled["site"]
    outline = {"type": "Polygon", "coordinates": [[[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]]]}
    ids = {}
    for name, material, density in (("North", "gravel", None), ("South", "clinker", 1.4), ("West", "sand", None)):
        r = a.post(f"/api/v1/sites/{site}/stockpiles", json={"name": name, "outline": outline, "material": material,
                                                              "density_t_m3": density})
        assert r.status_code == 201, r.text
        ids[name] = r.json()["id"]
    with p.db().session() as s:
        for k, (day, vols) in enumerate(((datetime(2024, 3, 1, 9), {"North": (200.0, 3.0), "South": (40.0, 1.0)}),
                                         (datetime(2024, 4, 1, 9), {"North": (150.0, 4.0)}))):
            sv = Survey(site_id=site, name=f"flight {k + 1}", flown_at=day)
            s.add(sv)
            s.flush()
            for state, scale in (("failed", 9.0), ("succeeded", 1.0)):     # a failed run's volumes are ignored
                run = Run(survey_id=sv.id, site_id=site, number=1 if state == "failed" else 2, state=state)
                s.add(run)
                s.flush()
                for name, (v, sig) in vols.items():
                    s.add(VolumeMeasurement(run_id=run.id, survey_id=sv.id, site_id=site, stockpile_id=ids[name],
                                            stockpile_name=name, base="plane", volume_m3=v * scale, cut_m3=v,
                                            fill_m3=0.0, area_m2=16.0, measured_at=day,
                                            details={"sigma_m3": sig, "ci95_m3": 1.96 * sig}))
    url = f"/api/v1/sites/{site}/inventory"
    doc = a.get(url, params={"date": "2024-04-15"}).json()
    rows = {r["stockpile"]: r for r in doc["stockpiles"]}
    assert rows["North"]["volume_m3"] == 150.0 and rows["North"]["survey"] == "flight 2"
    assert rows["North"]["change_m3"] == -50.0 and rows["North"]["change_sigma_m3"] == 5.0
    # gravel default 1.70 +- 0.10 t/m3: 255 t +- sqrt((1.7*4)^2 + (150*0.1)^2)
    assert rows["North"]["tonnes_t"] == 255.0
    assert rows["North"]["tonnes_sigma_t"] == pytest.approx(((1.7 * 4) ** 2 + 15.0 ** 2) ** 0.5, abs=0.006)
    assert rows["South"]["tonnes_t"] == 56.0 and rows["South"]["survey_date"] == "2024-03-01"
    assert rows["West"]["volume_m3"] is None and rows["West"]["status"].startswith("no survey")
    assert doc["totals"]["volume_m3"] == 190.0 and doc["totals"]["tonnes_t"] == 311.0
    early = a.get(url, params={"date": "2024-03-15"}).json()
    assert {r["stockpile"]: r["volume_m3"] for r in early["stockpiles"]}["North"] == 200.0
    csv_r = a.get(url, params={"date": "2024-04-15", "format": "csv"})
    assert csv_r.status_code == 200 and csv_r.headers["content-type"].startswith("text/csv")
    assert csv_r.text.splitlines()[0].startswith("stockpile,material,survey,survey_date,volume_m3")
    assert csv_r.text.splitlines()[-1].startswith("TOTAL,")
    x = a.get(url, params={"date": "2024-04-15", "format": "xlsx"})
    assert x.status_code == 200 and "attachment" in x.headers["content-disposition"]
    ws = load_workbook(io.BytesIO(x.content))["Inventory"]
    assert ws.cell(ws.max_row, 1).value == "TOTAL" and ws.cell(ws.max_row, 11).value == 311.0
    assert a.get(url, params={"date": "next week"}).status_code == 422
    assert a.get(url, params={"format": "pdf"}).status_code == 422
    assert b.get(url).status_code == 404 and tiled["p"].client().get(url).status_code == 401
