"""Where a scene's objects live in the bucket: the one place that spells its keys.

Inside a tenant's part of the bucket (`storage.stores.tenant_store`) a scene is the prefix
``scenes/<id>/``: the validated scene under ``input/`` (what the workers read), and while a
presigned upload is under way its files under ``staging/<field>/<name>`` (removed once the
scene is published). The bucket sweep reads whole-bucket keys, ``tenants/<t>/scenes/<id>/...``,
and earlier releases kept a record object and tombstones there (`legacy_import`).

Why one module: the routes, the sweep and the import each built these strings by hand, so a
change of layout had to be found in four packages.
"""

from __future__ import annotations

from bayesian_fields_service.storage.stores import TENANTS_ROOT

SCENES = "scenes"
INPUT = "input/"
STAGING = "staging/"
LEGACY_RECORD_NAME = "scene.json"
"""The name of the record object under ``tenants/<t>/scenes/<id>/`` in earlier releases."""


def scene_root(scene_id: str) -> str:
    """Everything of the scene, relative to its tenant: ``scenes/<id>/``."""
    return f"{SCENES}/{scene_id}/"


def input_prefix(scene_id: str) -> str:
    """The validated scene the workers read: ``scenes/<id>/input/``."""
    return scene_root(scene_id) + INPUT


def staging_prefix(scene_id: str) -> str:
    """The files of a presigned upload before completion: ``scenes/<id>/staging/``."""
    return scene_root(scene_id) + STAGING


def staging_key(scene_id: str, field: str, name: str) -> str:
    """One presigned file's object: ``scenes/<id>/staging/<field>/<name>``."""
    return f"{staging_prefix(scene_id)}{field}/{name}"


def bucket_scene_root(tenant: str, scene_id: str) -> str:
    """The scene's prefix in the whole bucket: ``tenants/<t>/scenes/<id>/``."""
    return f"{TENANTS_ROOT}/{tenant}/{scene_root(scene_id)}"


def bucket_scenes_of(tenant_root: str) -> str:
    """The prefix under which a tenant's scenes are listed (`tenant_root` is ``tenants/<t>/``)."""
    return f"{tenant_root}{SCENES}/"


def scene_of(key: str) -> tuple[str, str] | None:
    """(tenant, scene id) of a whole-bucket key under ``tenants/<t>/scenes/<id>/``, else None."""
    parts = key.split("/")
    if len(parts) < 5 or parts[0] != TENANTS_ROOT or parts[2] != SCENES or not parts[3]:
        return None
    return parts[1], parts[3]


def legacy_record_of(key: str) -> tuple[str, str] | None:
    """(tenant, scene id) when `key` is an earlier release's record object, else None."""
    parts = key.split("/")
    if len(parts) == 5 and parts[0] == TENANTS_ROOT and parts[2] == SCENES and parts[4] == LEGACY_RECORD_NAME:
        return parts[1], parts[3]
    return None


def legacy_tombstone(tenant: str, scene_id: str) -> str:
    """Where an earlier release marked a scene deleted: ``tenants/<t>/tombstones/scenes/<id>``."""
    return f"{TENANTS_ROOT}/{tenant}/tombstones/{SCENES}/{scene_id}"
