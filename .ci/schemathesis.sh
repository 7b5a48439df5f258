#!/usr/bin/env bash
# schemathesis against the live OpenAPI of a real stack (redis-server, rclone serve s3, uvicorn):
# no 5xx and no response that disagrees with the schema. Bounded: a 150 s generation budget inside
# a hard 5-minute timeout. Prints "schemathesis: N cases, exit status S".
set -euo pipefail
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD"
timeout 300 .venv/bin/python -m tests.services.support.live_stack --max-examples 25 --max-time 150
