"""Infra tests use the integration fixtures (real rclone S3 server, real redis-server), which the
root conftest registers for every directory."""
