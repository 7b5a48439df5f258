#!/bin/sh
# The S3 stand-in's three commands (see s3.Containerfile): serve DIR | ready | mb ENDPOINT.
# Credentials come from MINIO_ROOT_USER / MINIO_ROOT_PASSWORD, the variables the compose file
# already gives MinIO and its init job.
set -eu
user="${MINIO_ROOT_USER:?}"
password="${MINIO_ROOT_PASSWORD:?}"
s3() {  # rclone with an S3 remote at $1 given on the command line, no config file
  endpoint="$1"; shift
  rclone --config /dev/null --s3-provider Minio --s3-endpoint "$endpoint" \
    --s3-access-key-id "$user" --s3-secret-access-key "$password" "$@"
}
case "${1:-}" in
  serve) exec rclone serve s3 --config /dev/null --addr :9000 --auth-key "$user,$password" "${2:?serve DIR}" ;;
  ready) s3 http://127.0.0.1:9000 lsd :s3: >/dev/null ;;  # the S3 API answers, the key pair works
  mb)  # like `mc mb --ignore-existing`: a bucket that exists (a restart with the volume) is fine
    endpoint="${2:?mb ENDPOINT}"
    if ! s3 "$endpoint" lsf --dirs-only :s3: | grep -qx "${BUCKET:?}/"; then
      s3 "$endpoint" mkdir ":s3:$BUCKET"
    fi
    echo "bucket $BUCKET ready" ;;
  *) echo "usage: s3-standin serve DIR | ready | mb ENDPOINT" >&2; exit 2 ;;
esac
