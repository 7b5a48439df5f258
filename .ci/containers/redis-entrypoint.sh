#!/bin/sh
# Like the real image's entrypoint: a redis-server started with no config file listens on every
# interface with protected mode off (the container network is the boundary), so the other
# containers can reach it; any other command runs as given.
set -e
if [ "${1:-}" = "redis-server" ]; then
  shift
  exec redis-server --bind 0.0.0.0 --protected-mode no "$@"
fi
exec "$@"
