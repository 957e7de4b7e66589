"""Heights and coordinates the site uses (docs/datums.md): vertical datums (geoid models through pyproj,
grids installed, never downloaded), orthometric copies of DSMs, point clouds and point tables with the datum
written into each file, and site calibrations (localisations) onto a local grid."""
