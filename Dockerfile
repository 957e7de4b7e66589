# One image for the API, the workers and beat (docker-compose.yml picks the command).
FROM python:3.11-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    GEOREF_DATA_DIR=/data OMP_NUM_THREADS=1 NUMBA_CACHE_DIR=/opt/numba-cache

# open3d needs libusb and libgomp at run time; curl for the health checks; proj-data: the EGM96 geoid grid
RUN apt-get update -qq \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libusb-1.0-0 libgomp1 curl proj-data \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY pyproject.toml README.md ./
COPY georef_core ./georef_core
COPY backend ./backend
COPY worker ./worker
RUN pip install -q .
# numba kernels compiled into the image (minutes here, not in each container's first solve); numba only
# reads a cache directory it can write, hence NUMBA_CACHE_DIR owned by the runtime user
RUN python -m georef_core.warmup
# the GNSS kernels compiled ahead of time (georef_core/gnss/aot_build.py): `georef gnss solve` then starts without
# numba. For a generic x86-64 CPU (the image runs on other machines than the one that built it); the C compiler
# only for this step. A failure leaves numba's cached kernels in use (a message, not a failed build).
RUN apt-get update -qq \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends gcc libc6-dev \
 && python -m georef_core.gnss.aot_build --target-cpu generic \
 && apt-get purge -y -qq gcc libc6-dev && apt-get autoremove -y -qq && rm -rf /var/lib/apt/lists/*

RUN useradd --create-home --uid 10001 georef && mkdir -p /data && chown georef /data && chown -R georef /opt/numba-cache
USER georef
VOLUME /data
EXPOSE 8000

# default: the API (migrations run first; safe to run on every start). --http: uvicorn's httptools protocol
# with a deadline (GEOREF_REQUEST_HEADER_TIMEOUT_S, 408) and a size limit (GEOREF_MAX_REQUEST_HEADER_BYTES, 431)
# on request headers, which plain uvicorn lacks: the API holds against slow clients without nginx too
# (docs/security.md); --timeout-keep-alive: an idle kept-alive connection is closed after 15 s
CMD ["sh", "-c", "python -m backend.db.migrate && exec uvicorn backend.main:app --host 0.0.0.0 --port 8000 --workers ${API_WORKERS:-2} --proxy-headers --forwarded-allow-ips='*' --http backend.core.http_protocol:SettingsHttpProtocol --timeout-keep-alive 15"]
