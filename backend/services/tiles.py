"""Web map tiles (XYZ, Web Mercator) and the WMTS document of a run's rasters, for the browser map, QGIS,
ArcGIS and GDAL.

The layers are the outputs the steps declare with a `tile` style (georef_core.steps.contract.Output:
the dense step's ortho and dsm, the design step's difference, any plug-in step's raster), present in the
run. Tiles are rendered by georef_core.tiles.render from the stored COG's overviews and cached on disk
under the work folder, keyed by the source file's SHA-256 and the style version: a run's results never
change, so a cached tile is never stale (strong ETag, long Cache-Control). Access: the viewer role on the
run's site, with a session, an API token with the read scope, or a tile token (services/accounts.py
create_tile_token; permissions.require_run_for_tiles)."""

from __future__ import annotations

import os
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

from ..core.problems import BadRequest, Conflict, NotFound
from ..models import Run, RunOutput
from ..storage import blob_key
from . import steps_catalog
from .context import Ctx
from .permissions import require_run_for_tiles

CACHE_CONTROL = "private, max-age=604800, immutable"


@dataclass(frozen=True)
class LayerDecl:
    name: str          # the URL's {layer}: the output key (step_key when two steps declare the same key)
    step: str
    key: str
    path: str
    style: str
    title: str


def declared_layers() -> dict[str, LayerDecl]:
    """Every tileable output the steps declare, by layer name."""
    found = [(s, o) for s in steps_catalog.BY_NAME.values() for o in s.outputs if getattr(o, "tile", None)]
    keys = [o.key for _, o in found]
    out = {}
    for s, o in found:
        name = o.key if keys.count(o.key) == 1 else f"{s.name}_{o.key}"
        title = next((p.title for p in s.products if o.key in p.needs), o.description or o.key)
        out[name] = LayerDecl(name, s.name, o.key, o.path, o.tile, title)
    return out


class _InfoCache:
    """RasterInfo by (source sha256, style): small, computed once per raster (reads its coarsest overview)."""

    def __init__(self, size: int = 256):
        self.size, self.items, self.lock = size, OrderedDict(), threading.Lock()

    def get(self, key, build):
        with self.lock:
            v = self.items.get(key)
            if v is not None:
                self.items.move_to_end(key)
                return v
        v = build()
        with self.lock:
            self.items[key] = v
            while len(self.items) > self.size:
                self.items.popitem(last=False)
        return v


_infos = _InfoCache()


def _run_layers(ctx: Ctx, run_id: str) -> tuple[Run, dict[str, tuple[LayerDecl, RunOutput]]]:
    decl = declared_layers()
    run, rows = require_run_for_tiles(ctx, run_id, tuple({d.path for d in decl.values()}))
    return run, {n: (d, rows[d.path]) for n, d in decl.items() if d.path in rows}


def _layer(ctx: Ctx, run_id: str, layer: str) -> tuple[Run, LayerDecl, RunOutput]:
    run, layers = _run_layers(ctx, run_id)
    if layer not in layers:
        if layer in declared_layers() and run.state in ("queued", "running"):
            raise Conflict(f"layer {layer!r} not produced yet (run is {run.state})")
        raise NotFound(f"this run has no map layer {layer!r} (layers: {', '.join(sorted(layers)) or 'none'})")
    d, o = layers[layer]
    return run, d, o


def _tiles_root(ctx: Ctx) -> Path:
    return ctx.settings.resolved_work_dir() / "tiles"


def _atomic_write(dest: Path, data: bytes) -> None:
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=dest.parent, prefix=".part-")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, dest)


def _source(ctx: Ctx, o: RunOutput) -> Path:
    """A local path of the stored raster: the store's own file, or a copy fetched once into the work folder
    (object stores)."""
    local = ctx.storage.local_path(blob_key(o.sha256))
    if local is not None:
        return Path(local)
    dest = _tiles_root(ctx) / "sources" / f"{o.sha256}.tif"
    if not dest.exists():
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=dest.parent, prefix=".part-")
        os.close(fd)
        try:
            ctx.storage.fetch(blob_key(o.sha256), Path(tmp))
            os.replace(tmp, dest)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    return dest


def _info(ctx: Ctx, d: LayerDecl, o: RunOutput):
    from georef_core.tiles.render import raster_info

    src = _source(ctx, o)
    return src, _infos.get((o.sha256, d.style), lambda: raster_info(src, d.style))


def _check_tile(z: int, x: int, y: int) -> None:
    from georef_core.tiles.mercator import check_tile

    problem = check_tile(z, x, y)
    if problem:
        raise BadRequest(f"tile {z}/{x}/{y}: {problem}")


@dataclass
class TileImage:
    body: bytes
    etag: str
    empty: bool


def tile(ctx: Ctx, run_id: str, layer: str, z: int, x: int, y: int) -> TileImage:
    """The PNG of tile z/x/y (transparent outside the raster), from the disk cache or rendered now."""
    from georef_core.tiles.render import STYLE_VERSION, empty_png, render_tile

    run, d, o = _layer(ctx, run_id, layer)
    _check_tile(z, x, y)
    ctx.db.commit()    # everything is read: no transaction held while rendering
    etag = f'"{o.sha256[:20]}-{d.style}{STYLE_VERSION}-{z}-{x}-{y}"'
    cached = _tiles_root(ctx) / o.sha256[:2] / o.sha256 / f"{d.style}-v{STYLE_VERSION}" / str(z) / str(x) / f"{y}.png"
    if cached.exists():
        return TileImage(cached.read_bytes(), etag, False)
    src, info = _info(ctx, d, o)
    t = render_tile(src, info, z, x, y)
    if t.png is None:
        return TileImage(empty_png(), etag, True)
    _atomic_write(cached, t.png)
    return TileImage(t.png, etag, False)


def legend(ctx: Ctx, run_id: str, layer: str) -> dict:
    from georef_core.tiles.render import legend as make_legend

    run, d, o = _layer(ctx, run_id, layer)
    ctx.db.commit()
    _, info = _info(ctx, d, o)
    return {"run_id": run_id, "layer": layer, "title": d.title, **make_legend(info)}


def layers(ctx: Ctx, run_id: str, base_url: str) -> list[dict]:
    """The run's map layers: name, title, style, extent, zoom range, tile URL template and legend URL."""
    run, found = _run_layers(ctx, run_id)
    ctx.db.commit()
    out = []
    for name, (d, o) in sorted(found.items()):
        _, info = _info(ctx, d, o)
        out.append({"name": name, "title": d.title, "style": d.style, "step": d.step, "source": d.path,
                    "lonlat_bounds": list(info.lonlat_bounds), "min_zoom": 0, "max_zoom": info.max_zoom,
                    "tiles": f"{base_url}/runs/{run_id}/tiles/{name}/{{z}}/{{x}}/{{y}}.png",
                    "legend": f"{base_url}/runs/{run_id}/tiles/{name}/legend.json"})
    return out


def wmts_capabilities(ctx: Ctx, run_id: str, base_url: str, url_token: str | None) -> bytes:
    """The WMTS 1.0.0 document of the run's layers; the tile URL templates carry `url_token` (a tile token
    the document was asked with) so that a client that read it with the token in the URL gets its tiles."""
    from urllib.parse import quote

    from georef_core.tiles.wmts import Layer, capabilities

    run, found = _run_layers(ctx, run_id)
    ctx.db.commit()
    q = f"?token={quote(url_token, safe='')}" if url_token else ""
    lyrs = []
    for name, (d, o) in sorted(found.items()):
        _, info = _info(ctx, d, o)
        lyrs.append(Layer(name, f"{d.title} (run {run.number})", f"{d.step} step output {d.path}, style {d.style}",
                          info, f"{base_url}/runs/{run_id}/tiles/{name}/{{TileMatrix}}/{{TileCol}}/{{TileRow}}.png{q}"))
    return capabilities(f"Georef run {run.number}", lyrs)
