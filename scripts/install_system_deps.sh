#!/usr/bin/env bash
# System packages Georef needs beyond Python wheels (Debian). Idempotent; does nothing when all are present.
set -euo pipefail
need=()
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || need+=(libusb-1.0-0)   # open3d
[ -x /usr/bin/chromium ] || need+=(chromium)                                    # browser end-to-end tests (Playwright)
command -v npm >/dev/null || need+=(nodejs npm)                                 # front-end build
[ -f /usr/share/proj/egm96_15.gtx ] || need+=(proj-data)                        # EGM96 geoid grid (docs/datums.md)
command -v gdalinfo >/dev/null || need+=(gdal-bin)                             # tests: GDAL (QGIS's reader) reads the tile service
command -v pdftoppm >/dev/null || need+=(poppler-utils)                        # tests: the PDF report rendered to PNG pages, its text
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}"
  else
    echo "Please install these Debian packages: ${need[*]} (sudo apt-get install ${need[*]})" >&2
  fi
fi
