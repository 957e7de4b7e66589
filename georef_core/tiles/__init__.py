"""Web map tiles of a run's rasters (orthophoto, DSM, design difference): Web Mercator (EPSG:3857) XYZ
tiles rendered from the cloud-optimised GeoTIFF's overviews (`render`), the tile grid arithmetic
(`mercator`) and the OGC WMTS capabilities document QGIS and GDAL read (`wmts`). No web code: the API
(backend/services/tiles.py) checks access, caches and serves what these functions return."""
