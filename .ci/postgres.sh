#!/usr/bin/env bash
# Starts a PostgreSQL server on 127.0.0.1:5432 with trust auth for local connections (what the
# tests expect on a CI machine), from Debian's packages: the first installed cluster if there is
# one, else a new cluster in /tmp. Prints what it did.
set -euo pipefail
version="$(ls /usr/lib/postgresql 2>/dev/null | sort -V | tail -1)"
if [ -z "$version" ]; then echo "postgres.sh: no PostgreSQL installed" >&2; exit 1; fi
bin="/usr/lib/postgresql/$version/bin"
if command -v pg_lsclusters >/dev/null 2>&1 && pg_lsclusters -h | grep -q .; then
  read -r ver name _ <<<"$(pg_lsclusters -h | head -1)"
  conf="/etc/postgresql/$ver/$name"
  # trust for loopback TCP (a throwaway CI machine; never a deployment setting)
  sed -i -E 's/^(host\s+all\s+all\s+(127\.0\.0\.1\/32|::1\/128)\s+)\S+/\1trust/' "$conf/pg_hba.conf"
  pg_ctlcluster --skip-systemctl-redirect "$ver" "$name" start || pg_ctlcluster --skip-systemctl-redirect "$ver" "$name" restart
  echo "postgres.sh: started cluster $ver/$name"
else
  data=/tmp/bfields-pg
  run=(); [ "$(id -u)" = 0 ] && run=(runuser -u postgres --)
  mkdir -p "$data" && chown postgres "$data" 2>/dev/null || true
  [ -f "$data/PG_VERSION" ] || "${run[@]}" "$bin/initdb" -D "$data" -U postgres --auth=trust >/dev/null
  "${run[@]}" "$bin/pg_ctl" -D "$data" -o "-h 127.0.0.1 -p 5432 -k /tmp" -l "$data/log" -w start
  echo "postgres.sh: started a new cluster in $data"
fi
for _ in $(seq 30); do pg_isready -q -h 127.0.0.1 -p 5432 && exit 0; sleep 1; done
echo "postgres.sh: no answer on 127.0.0.1:5432" >&2; exit 1
