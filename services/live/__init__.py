"""Everything the service keeps in Redis or sends through the broker, and nothing else does:
the keys (`redis_keys`), replies as text (`redis_text`), the heartbeat locks of stages and cache
fills (`heartbeat_lock`, `single_flight`), the duration histograms (`metrics`) and the Celery
adapter that sends a job's stages and reads the queues (`broker`).

Why one package: what Redis holds is disposable (losing it loses nothing but progress), and a key
or a broker detail spelled in two places is an interface nobody sees. `tests/services/live`
checks that no module outside this package spells a ``bf:`` key or imports kombu. The Celery app
itself is built by the worker (`worker.celery_app`) and handed in, so this package imports no
layer above it.
"""
