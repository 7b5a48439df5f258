"""The tests' plugin on the service's hook points (`bayesian_fields_service.hooks`): pause points
and the encoder call log, installed into the processes a test starts by
``BFIELDS_HOOKS_PLUGINS=["tests.services.support.service_hooks"]`` (`PLUGIN_ENV`; the test
environments put the repository on ``PYTHONPATH``).

Pause points. Why: the races between `complete`, `delete` and job submission, and a worker killed
or a database lost at one step of a stage, are decided by a few storage calls; hoping that threads
hit them in the right order proves little. At each hook point a process checks whether a test has
armed the pause named after it (Redis key ``bf:test:pause:<name>`` holding the scene or job id);
if so it says it arrived (``bf:test:reached:<name>:<id>``) and waits until the test releases it
(``bf:test:resume:<name>:<id>``) or `PAUSE_LIMIT_S` passes. Unarmed, a point costs one Redis GET.
The pause names (`PAUSE_NAMES`, ``stage:<stage>:before_lock``, ``progress:<step>:<fraction>``)
are the ones the tests arm; `arm`, `wait_reached`, `resume` and `disarm` are the test's side.

Encoder call log. With ``TEST_HOOKS_ENCODER_CALL_LOG`` set to a file in a worker's environment,
the worker's encoder appends one line ``<pid> <images>`` per image batch it encodes (O_APPEND: one
whole line per write, whatever the number of processes), which lets a test count perception work
across processes.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import Any

import redis

from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.hooks import HookRegistry

#: The service environment entry that installs this plugin.
PLUGIN_ENV = {"BFIELDS_HOOKS_PLUGINS": json.dumps([__name__])}

#: A worker's environment variable naming the encoder call log (read by this plugin, no setting).
ENCODER_CALL_LOG_ENV = "TEST_HOOKS_ENCODER_CALL_LOG"

#: The longest a request ever waits at a point (a test that died must not hang the API).
PAUSE_LIMIT_S = 30.0

#: The pause names of the scene routes' hook points (context: scene_id).
PAUSE_NAMES = {
    "scene.complete.claimed": "complete:claimed",
    "scene.complete.fetched": "complete:fetched",
    "scene.complete.before_publish": "complete:before_publish",
    "scene.complete.publishing": "complete:publishing",
    "scene.delete.marked": "delete:marked",
}


def armed_key(point: str) -> str:
    """Set by a test to the scene (or job) id the pause `point` holds ..."""
    return f"bf:test:pause:{point}"


def reached_key(point: str, held_id: str) -> str:
    """... set by the process when it arrives there ..."""
    return f"bf:test:reached:{point}:{held_id}"


def resume_key(point: str, held_id: str) -> str:
    """... and set by the test to let it go on."""
    return f"bf:test:resume:{point}:{held_id}"


class Pauses:
    """The process's side: wait at a pause a test armed. The Redis client is made on first use,
    so a forked worker child never shares its parent's socket."""

    def __init__(self, redis_url: str) -> None:
        self._url = redis_url
        self._client: redis.Redis | None = None
        self._lock = threading.Lock()

    def client(self) -> redis.Redis:
        with self._lock:
            if self._client is None:
                self._client = redis.Redis.from_url(self._url, socket_timeout=10, socket_connect_timeout=5)
            return self._client

    def pause(self, name: str, held_id: str) -> None:
        """Wait at pause `name` if a test armed it for `held_id`."""
        client = self.client()
        armed = client.get(armed_key(name))
        if armed is None or armed.decode() != held_id:
            return
        client.set(reached_key(name, held_id), b"1", ex=120)
        resume = resume_key(name, held_id)
        deadline = time.monotonic() + PAUSE_LIMIT_S
        while time.monotonic() < deadline and not client.exists(resume):
            time.sleep(0.02)
        client.delete(resume)


def counting_encoder(log_file: Path) -> Any:
    """A wrapper of the encoder that logs each image batch to `log_file` (see the module's text)."""

    def wrap(encoder: Any) -> Any:
        class Counting:
            model_id = encoder.model_id
            dim = encoder.dim

            def encode_images(self, images: list) -> Any:
                fd = os.open(log_file, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
                try:
                    os.write(fd, f"{os.getpid()} {len(images)}\n".encode())
                finally:
                    os.close(fd)
                return encoder.encode_images(images)

            def encode_texts(self, texts: list[str]) -> Any:
                return encoder.encode_texts(texts)

        return Counting()

    return wrap


def install(registry: HookRegistry, settings: ServiceSettings) -> None:
    """Register the pause points on every hook point, and the encoder log when its variable is set."""
    pauses = Pauses(settings.redis_url)
    for point, name in PAUSE_NAMES.items():
        registry.on(point, lambda scene_id, _name=name, **_: pauses.pause(_name, scene_id))
    registry.on(
        "stage.before_lock",
        lambda stage, scene_id, **_: pauses.pause(f"stage:{stage}:before_lock", scene_id),
    )
    registry.on(
        "stage.progress",
        lambda step, fraction, job_id, **_: pauses.pause(f"progress:{step}:{fraction:g}", job_id),
    )
    log = os.environ.get(ENCODER_CALL_LOG_ENV)
    if log:
        registry.wrap_with("encoder", counting_encoder(Path(log)))


# ---- the test's side ---------------------------------------------------------------------------


def arm(rdb: redis.Redis, point: str, held_id: str) -> None:
    """Hold the next process that reaches pause `point` for `held_id`."""
    rdb.set(armed_key(point), held_id, ex=120)


def wait_reached(rdb: redis.Redis, point: str, held_id: str, timeout_s: float = 20) -> None:
    """Wait until a process is held at pause `point` for `held_id` (fails after `timeout_s`)."""
    deadline = time.monotonic() + timeout_s
    while not rdb.exists(reached_key(point, held_id)):
        assert time.monotonic() < deadline, f"the service never reached pause point {point}"
        time.sleep(0.02)


def disarm(rdb: redis.Redis, point: str) -> None:
    """Hold no further process at `point` (one held there stays held until resumed or its limit)."""
    rdb.delete(armed_key(point))


def resume(rdb: redis.Redis, point: str, held_id: str) -> None:
    """Disarm `point` and let the process held there for `held_id` go on."""
    disarm(rdb, point)
    rdb.set(resume_key(point, held_id), b"1", ex=120)
