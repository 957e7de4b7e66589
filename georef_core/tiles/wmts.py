"""The OGC WMTS 1.0.0 capabilities document (RESTful, GoogleMapsCompatible tile matrix set) of a run's
tile layers: what QGIS ("WMS/WMTS" connection), ArcGIS and GDAL's WMTS driver read to find the layers,
their extent, zoom levels and the URL template of their tiles."""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import escape, quoteattr

from .mercator import ORIGIN_M, TILE_PX, tile_size_m
from .render import RasterInfo

TMS_ID = "GoogleMapsCompatible"
_PIXEL_M = 0.00028     # the standardised rendering pixel of WMTS scale denominators


@dataclass
class Layer:
    name: str
    title: str
    abstract: str
    info: RasterInfo
    url_template: str      # with {TileMatrix}, {TileCol}, {TileRow}


def _limits(info: RasterInfo, z: int) -> tuple[int, int, int, int]:
    """(min_row, max_row, min_col, max_col) of the tiles of zoom z that touch the raster."""
    s = tile_size_m(z)
    n = 1 << z
    w, so, e, no = info.mercator_bounds
    c0, c1 = int((w + ORIGIN_M) // s), int((e + ORIGIN_M) // s)
    r0, r1 = int((ORIGIN_M - no) // s), int((ORIGIN_M - so) // s)
    clip = lambda v: max(0, min(n - 1, v))   # noqa: E731
    return clip(r0), clip(r1), clip(c0), clip(c1)


def capabilities(title: str, layers: list[Layer]) -> bytes:
    max_z = max((lyr.info.max_zoom for lyr in layers), default=0)
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<Capabilities xmlns="http://www.opengis.net/wmts/1.0" xmlns:ows="http://www.opengis.net/ows/1.1" '
           'xmlns:xlink="http://www.w3.org/1999/xlink" version="1.0.0">',
           "<ows:ServiceIdentification>", f"<ows:Title>{escape(title)}</ows:Title>",
           "<ows:ServiceType>OGC WMTS</ows:ServiceType>", "<ows:ServiceTypeVersion>1.0.0</ows:ServiceTypeVersion>",
           "</ows:ServiceIdentification>", "<Contents>"]
    for lyr in layers:
        i = lyr.info
        lon0, lat0, lon1, lat1 = i.lonlat_bounds
        x0, y0, x1, y1 = i.mercator_bounds
        out += ["<Layer>", f"<ows:Title>{escape(lyr.title)}</ows:Title>",
                f"<ows:Abstract>{escape(lyr.abstract)}</ows:Abstract>",
                f"<ows:WGS84BoundingBox><ows:LowerCorner>{lon0:.9f} {lat0:.9f}</ows:LowerCorner>"
                f"<ows:UpperCorner>{lon1:.9f} {lat1:.9f}</ows:UpperCorner></ows:WGS84BoundingBox>",
                f'<ows:BoundingBox crs="urn:ogc:def:crs:EPSG::3857"><ows:LowerCorner>{x0:.3f} {y0:.3f}'
                f"</ows:LowerCorner><ows:UpperCorner>{x1:.3f} {y1:.3f}</ows:UpperCorner></ows:BoundingBox>",
                f"<ows:Identifier>{escape(lyr.name)}</ows:Identifier>",
                '<Style isDefault="true"><ows:Identifier>default</ows:Identifier></Style>',
                "<Format>image/png</Format>", "<TileMatrixSetLink>", f"<TileMatrixSet>{TMS_ID}</TileMatrixSet>",
                "<TileMatrixSetLimits>"]
        for z in range(0, i.max_zoom + 1):
            r0, r1, c0, c1 = _limits(i, z)
            out.append(f"<TileMatrixLimits><TileMatrix>{z}</TileMatrix><MinTileRow>{r0}</MinTileRow>"
                       f"<MaxTileRow>{r1}</MaxTileRow><MinTileCol>{c0}</MinTileCol><MaxTileCol>{c1}</MaxTileCol>"
                       "</TileMatrixLimits>")
        out += ["</TileMatrixSetLimits>", "</TileMatrixSetLink>",
                f'<ResourceURL format="image/png" resourceType="tile" template={quoteattr(lyr.url_template)}/>',
                "</Layer>"]
    out += ["<TileMatrixSet>", f"<ows:Identifier>{TMS_ID}</ows:Identifier>",
            "<ows:SupportedCRS>urn:ogc:def:crs:EPSG::3857</ows:SupportedCRS>",
            "<WellKnownScaleSet>urn:ogc:def:wkss:OGC:1.0:GoogleMapsCompatible</WellKnownScaleSet>"]
    for z in range(0, max_z + 1):
        res = tile_size_m(z) / TILE_PX
        out.append(f"<TileMatrix><ows:Identifier>{z}</ows:Identifier><ScaleDenominator>{res / _PIXEL_M:.10f}"
                   f"</ScaleDenominator><TopLeftCorner>{-ORIGIN_M:.10f} {ORIGIN_M:.10f}</TopLeftCorner>"
                   f"<TileWidth>{TILE_PX}</TileWidth><TileHeight>{TILE_PX}</TileHeight>"
                   f"<MatrixWidth>{1 << z}</MatrixWidth><MatrixHeight>{1 << z}</MatrixHeight></TileMatrix>")
    out += ["</TileMatrixSet>", "</Contents>", "</Capabilities>"]
    return "\n".join(out).encode()
