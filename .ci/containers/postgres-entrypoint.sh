#!/bin/sh
# First start (an empty data volume): initdb with scram-sha-256 for TCP connections, the
# POSTGRES_USER role with POSTGRES_PASSWORD as its owner, then POSTGRES_DB. Every start: the
# server in the foreground as PID 1, listening on every interface of the container.
# SIGINT (the image's stop signal) is PostgreSQL's "fast" shutdown, as in the real image.
set -eu
bin="$(ls -d /usr/lib/postgresql/*/bin | sort -V | tail -1)"
user="${POSTGRES_USER:-postgres}"
db="${POSTGRES_DB:-$user}"
if [ ! -s "$PGDATA/PG_VERSION" ]; then
  : "${POSTGRES_PASSWORD:?the stand-in needs POSTGRES_PASSWORD, like the real image}"
  pwfile="$(mktemp)"
  printf '%s\n' "$POSTGRES_PASSWORD" >"$pwfile"
  "$bin/initdb" -D "$PGDATA" -U "$user" --pwfile="$pwfile" --auth-local=trust --auth-host=scram-sha-256 >/dev/null
  rm -f "$pwfile"
  echo "host all all all scram-sha-256" >>"$PGDATA/pg_hba.conf"
  "$bin/pg_ctl" -D "$PGDATA" -o "-c listen_addresses=''" -w start >/dev/null
  [ "$db" = postgres ] || "$bin/psql" -v ON_ERROR_STOP=1 -U "$user" -d postgres -q \
    -c "CREATE DATABASE \"$db\" OWNER \"$user\""
  "$bin/pg_ctl" -D "$PGDATA" -m fast -w stop >/dev/null
  echo "postgres-entrypoint: initialised $PGDATA (role $user, database $db)"
fi
exec "$bin/postgres" -D "$PGDATA" -c listen_addresses='*'
