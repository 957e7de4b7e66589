#!/bin/sh
# Stand-ins for the public images docker-compose.yml names, built from Debian packages, for a machine
# that reaches a Debian mirror and PyPI but no container registry (an air-gapped site with a local
# mirror; the development machines, where Docker Hub does not resolve). docs/deploy.md says what differs.
#
#   sudo sh scripts/standin_base_images.sh          # needs debootstrap and a running Docker daemon
#   docker compose up -d --build
#
# Built under the tags docker-compose.yml and the Dockerfile use:
#   python:3.11-slim-bookworm  Debian bookworm's python3 (3.11), pip without the "externally managed" guard
#   postgres:16-alpine         Debian's PostgreSQL 15, initialised from POSTGRES_USER/_PASSWORD/_DB like the
#                              official image (data in /var/lib/postgresql/data)
#   redis:7-alpine             Debian's Redis 7.0 (working directory /data)
#   nginx:1.27-alpine          Debian's nginx 1.22, only /etc/nginx/conf.d/*.conf served (as in the official image)
#   minio/minio:latest         moto's S3 server (PyPI), answering `minio server ...` and `mc ready local`;
#                              it keeps objects in memory, not in /data
# An image already present under one of these tags (the real one) is left alone unless --force is given.
set -eu

MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
FORCE=0
[ "${1:-}" = "--force" ] && FORCE=1
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT

have() { [ "$FORCE" = 0 ] && docker image inspect "$1" >/dev/null 2>&1; }

if ! docker image inspect georef-standin/debian:bookworm >/dev/null 2>&1; then
  echo "debootstrap bookworm (minbase) from $MIRROR ..."
  debootstrap --variant=minbase bookworm "$WORK/rootfs" "$MIRROR" >"$WORK/debootstrap.log"
  # the host's own CAs (where outgoing TLS goes through an inspecting proxy, pip needs its CA): the
  # images' ca-certificates package adds them to the bundle it builds
  mkdir -p "$WORK/rootfs/usr/local/share/ca-certificates"
  cp /usr/local/share/ca-certificates/*.crt "$WORK/rootfs/usr/local/share/ca-certificates/" 2>/dev/null || true
  tar -C "$WORK/rootfs" -c . | docker import - georef-standin/debian:bookworm >/dev/null
fi

build() {   # build TAG  (Dockerfile on stdin)
  if have "$1"; then echo "$1: present, kept"; return; fi
  mkdir -p "$WORK/ctx-$2"
  cat >"$WORK/ctx-$2/Dockerfile"
  [ -f "$WORK/ctx-$2/entry.sh" ] || : >"$WORK/ctx-$2/entry.sh"
  echo "building stand-in $1 ..."
  docker build -q --network host -t "$1" "$WORK/ctx-$2" >/dev/null
}

APT='apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends'

build python:3.11-slim-bookworm python <<EOF
FROM georef-standin/debian:bookworm
RUN $APT python3 python3-pip python3-venv ca-certificates && rm -rf /var/lib/apt/lists/* \
 && rm -f /usr/lib/python3*/EXTERNALLY-MANAGED \
 && ln -sf /usr/bin/python3 /usr/local/bin/python && ln -sf /usr/bin/pip3 /usr/local/bin/pip \
 && printf '[global]\ncert = /etc/ssl/certs/ca-certificates.crt\n' >/etc/pip.conf
CMD ["python3"]
EOF

mkdir -p "$WORK/ctx-postgres"
cat >"$WORK/ctx-postgres/entry.sh" <<'EOF'
#!/bin/sh
# the official image's contract: initialise an empty data folder from POSTGRES_* and run postgres
set -e
export PGDATA=${PGDATA:-/var/lib/postgresql/data}
mkdir -p "$PGDATA" /run/postgresql && chown -R postgres:postgres "$PGDATA" /run/postgresql && chmod 700 "$PGDATA"
if [ ! -s "$PGDATA/PG_VERSION" ]; then
  user=${POSTGRES_USER:-postgres}
  db=${POSTGRES_DB:-$user}
  printf '%s' "${POSTGRES_PASSWORD:?POSTGRES_PASSWORD is required}" >/tmp/pwfile && chown postgres /tmp/pwfile
  runuser -u postgres -- initdb -D "$PGDATA" -U "$user" --pwfile=/tmp/pwfile --encoding=UTF8 --locale=C.UTF-8 \
    --auth-local=trust --auth-host=scram-sha-256 >/dev/null
  rm -f /tmp/pwfile
  echo "host all all all scram-sha-256" >>"$PGDATA/pg_hba.conf"
  if [ "$db" != postgres ]; then
    runuser -u postgres -- pg_ctl -D "$PGDATA" -o "-c listen_addresses=''" -w start >/dev/null
    runuser -u postgres -- psql -q -U "$user" -d postgres -c "CREATE DATABASE \"$db\""
    runuser -u postgres -- pg_ctl -D "$PGDATA" -m fast -w stop >/dev/null
  fi
fi
exec runuser -u postgres -- postgres -D "$PGDATA" -c listen_addresses='*'
EOF
build postgres:16-alpine postgres <<EOF
FROM georef-standin/debian:bookworm
RUN $APT postgresql && rm -rf /var/lib/apt/lists/*
ENV PATH=/usr/lib/postgresql/15/bin:\$PATH
COPY entry.sh /usr/local/bin/docker-entrypoint.sh
RUN chmod +x /usr/local/bin/docker-entrypoint.sh
EXPOSE 5432
ENTRYPOINT ["/usr/local/bin/docker-entrypoint.sh"]
EOF

mkdir -p "$WORK/ctx-redis"
cat >"$WORK/ctx-redis/entry.sh" <<'EOF'
#!/bin/sh
# the official image is built with protected mode off (its network is the compose network)
exec /usr/bin/redis-server "$@" --protected-mode no
EOF
build redis:7-alpine redis <<EOF
FROM georef-standin/debian:bookworm
RUN $APT redis-server && rm -rf /var/lib/apt/lists/* && mkdir -p /data
COPY entry.sh /usr/local/bin/redis-server
RUN chmod +x /usr/local/bin/redis-server
WORKDIR /data
EXPOSE 6379
CMD ["redis-server"]
EOF

build nginx:1.27-alpine nginx <<EOF
FROM georef-standin/debian:bookworm
RUN $APT nginx && rm -rf /var/lib/apt/lists/* /etc/nginx/sites-enabled/* /etc/nginx/conf.d/* \
 && ln -sf /dev/stdout /var/log/nginx/access.log && ln -sf /dev/stderr /var/log/nginx/error.log
EXPOSE 80
CMD ["nginx", "-g", "daemon off;"]
EOF

mkdir -p "$WORK/ctx-minio"
cat >"$WORK/ctx-minio/entry.sh" <<'EOF'
#!/bin/sh
# `minio server DIR [--console-address A]` -> moto's S3 server on port 9000
[ "${1:-}" = server ] || { echo "stand-in minio: only 'server' is supported" >&2; exit 2; }
exec moto_server -H 0.0.0.0 -p 9000
EOF
cat >"$WORK/ctx-minio/mc" <<'EOF'
#!/bin/sh
# `mc ready local`: the S3 endpoint answers
exec python3 -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:9000/', timeout=3)"
EOF
build minio/minio:latest minio <<EOF
FROM python:3.11-slim-bookworm
RUN pip install -q 'moto[server]'
COPY entry.sh /usr/bin/minio
COPY mc /usr/local/bin/mc
RUN chmod +x /usr/bin/minio /usr/local/bin/mc
EXPOSE 9000
ENTRYPOINT ["/usr/bin/minio"]
EOF

echo "stand-in images ready: docker compose up -d --build"
