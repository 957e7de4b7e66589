"""Deliverables a surveyor and a site manager take away from a run: contours (GeoJSON, GeoPackage, DXF),
the surveyed TIN as LandXML, vector products as DXF / GeoPackage / Shapefile, tables as CSV / XLSX and the
orthophoto as a KMZ overlay (docs/deliverables.md, sections "Contours" and "Exports").

One module per job: ``surface`` (reading an elevation GeoTIFF and its CRS, vertical one included),
``contours`` (tracing), ``dxf_writer``, ``vector_writer`` (GeoJSON, GeoPackage, Shapefile),
``landxml_writer``, ``kmz_writer``, ``tables_writer`` (CSV, XLSX) and ``exports`` (a run folder's exports).
"""
