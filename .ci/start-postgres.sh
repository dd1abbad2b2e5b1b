#!/usr/bin/env bash
# Start a throwaway PostgreSQL server on loopback for the sweep tests; print its URL on stdout.
# Installs Debian's postgresql package when no server binaries are present. Needs root (the server runs as the
# 'postgres' user). Stop it with: pg_ctl -D "$(dirname "$0")/pgdata" stop (done by .ci/run).
set -euo pipefail
port=${SB3_MACB_PG_PORT:-55432}
here=$(cd "$(dirname "$0")" && pwd)
bin=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1 || true)
if [ -z "$bin" ]; then
  (apt-get install -y -q postgresql || (apt-get update -q && apt-get install -y -q postgresql)) >&2
  bin=$(ls -d /usr/lib/postgresql/*/bin | sort -V | tail -n 1)
fi
data="$here/pgdata"
rm -rf "$data" && mkdir -p "$data" && chown postgres "$data"
runuser -u postgres -- "$bin/initdb" -D "$data" -A trust -U postgres >/dev/null
runuser -u postgres -- "$bin/pg_ctl" -D "$data" -l "$data/server.log" -w \
  -o "-p $port -k $data -c listen_addresses=127.0.0.1" start >&2
runuser -u postgres -- "$bin/createdb" -h 127.0.0.1 -p "$port" -U postgres sb3macb
echo "postgresql://postgres@127.0.0.1:$port/sb3macb"
