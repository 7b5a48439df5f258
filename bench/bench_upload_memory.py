"""Peak memory of the upload validator's splat check against the file's size, before and after.

Why: the API validates every upload before storing it; with the whole-file read (`read_ply`) a
656 MB splat took the API to 1.7 GiB. The streamed check (`scene.ply_scan.scan_ply`) reads the
body in chunks. This writes synthetic INRIA splats like the reported one (SH degree 3, 20 extra
properties: 328 bytes a Gaussian) of the sizes asked for, without holding them in memory, and
runs each check in a fresh subprocess, reporting its peak resident size (ru_maxrss) beside the
interpreter's own (numpy and the library imported, nothing read).

    python bench/bench_upload_memory.py                      # 100 MB and 1 GB, both checks
    python bench/bench_upload_memory.py --sizes 4000 --modes after
    python bench/bench_upload_memory.py --sizes 656 --api       # the API process itself
    python bench/bench_upload_memory.py --bombs                 # one hostile file per format

`--api` starts the API (uvicorn, local storage backend, alignment check off) and uploads the
splat with a one-frame camera file through `POST /v1/scenes`, then reads the API process's peak
resident size (VmHWM) before and after the request.

`--bombs` uploads each file of `bench/splat_bombs.py` (files that declare far more than they
carry: an all-zero SPZ, constant WebPs, a meta.json that inflates to 600 MB, ...) through the API
in turn, each to a fresh API process, and prints the status, the answer and the API's peak growth
during the request (issue 30's bound: about 150 MiB whatever the file declares).

Run by hand; not part of CI. Needs free disk of the largest size (in --dir) and, for 'before',
memory of about 2.7x the largest size.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PROPS = (
    ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    + [f"f_rest_{i}" for i in range(45)]
    + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    + [f"extra_{i}" for i in range(20)]
)
ROW = np.dtype([(p, "<f4") for p in PROPS])
CHUNK_ROWS = 100_000


def write_splat(path: Path, megabytes: float) -> int:
    """A valid splat of about `megabytes` MB (10^6 bytes), written chunk by chunk; returns N."""
    n = int(megabytes * 1e6 // ROW.itemsize)
    header = "ply\nformat binary_little_endian 1.0\n" + f"element vertex {n}\n"
    header += "".join(f"property float {p}\n" for p in PROPS) + "end_header\n"
    rng = np.random.default_rng(0)
    with open(path, "wb") as f:
        f.write(header.encode())
        for start in range(0, n, CHUNK_ROWS):
            m = min(CHUNK_ROWS, n - start)
            rows = np.zeros(m, dtype=ROW)
            for p in PROPS:
                rows[p] = rng.normal(size=m).astype(np.float32)
            for p in ("scale_0", "scale_1", "scale_2"):
                rows[p] = rng.uniform(-6, -3, size=m)
            rows["rot_0"] += 2.0
            rows.tofile(f)
    return n


def child(mode: str, path: str) -> None:
    """Run one check and print the peak resident size in MiB."""
    from bayesian_fields_core.checks.alignment import GEOMETRY_MAX_GAUSSIANS
    from bayesian_fields_core.scene.ply import read_ply
    from bayesian_fields_core.scene.ply_scan import sample_index, scan_ply
    from bayesian_fields_core.scene.sanity import splat_warnings

    t0 = time.perf_counter()
    if mode == "before":  # what the validator did: whole splat, warnings, the alignment sample
        g = read_ply(path)
        splat_warnings(g)
        g.subset(sample_index(len(g), GEOMETRY_MAX_GAUSSIANS))
    elif mode == "after":
        scan_ply(path, sample_size=GEOMETRY_MAX_GAUSSIANS)
    seconds = time.perf_counter() - t0
    print(f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.1f} {seconds:.2f}")


def measure(mode: str, path: Path) -> tuple[float, float]:
    out = subprocess.run(
        [sys.executable, __file__, "--child", mode, str(path)], capture_output=True, text=True, check=True
    ).stdout.split()
    return float(out[0]), float(out[1])


def _vm_hwm_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc status")


def _bench_database() -> str:
    """A new database on the machine's PostgreSQL (dropped at this process's exit)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from tests.integration.fixtures.postgres import create_database

    return create_database()


def measure_api(path: Path, workdir: Path) -> tuple[float, float, int, str]:
    """(API peak MiB after start, after the upload, HTTP status, answer) for one upload of `path`."""
    import io
    import json
    import os
    import socket

    import httpx
    from PIL import Image

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    env = {
        **os.environ,
        "BFIELDS_STORAGE_BACKEND": "local",
        "BFIELDS_LOCAL_STORAGE_ROOT": str(workdir / "store"),
        "BFIELDS_API_KEYS": json.dumps({"bench-key": "bench"}),
        "BFIELDS_MAX_UPLOAD_BYTES": str(8 * 2**30),
        "TMPDIR": str(workdir),
        # the records live in PostgreSQL (issue 28): a database of the bench's own on the machine's server
        "BFIELDS_DATABASE_URL": os.environ.get("BFIELDS_DATABASE_URL") or _bench_database(),
    }
    uvicorn = Path(sys.executable).parent / "uvicorn"
    argv = [
        str(uvicorn),
        "bayesian_fields_service.api.app:app",
        "--port",
        str(port),
        "--log-level",
        "warning",
    ]
    proc = subprocess.Popen(argv, env=env)
    try:
        base_url = f"http://127.0.0.1:{port}"
        for _ in range(300):
            try:
                if httpx.get(f"{base_url}/healthz", timeout=1).status_code < 600:
                    break
            except httpx.HTTPError:
                time.sleep(0.1)
        started = _vm_hwm_mib(proc.pid)
        png = io.BytesIO()
        Image.new("RGB", (8, 8), (128, 128, 128)).save(png, format="PNG")
        pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
        cams = {"fl_x": 8, "fl_y": 8, "cx": 4, "cy": 4, "w": 8, "h": 8,
                "frames": [{"file_path": "images/a.png", "transform_matrix": pose}]}  # fmt: skip
        with open(path, "rb") as splat:
            resp = httpx.post(
                f"{base_url}/v1/scenes",
                headers={"X-API-Key": "bench-key"},
                data={"alignment_check": "false"},
                files=[
                    ("splat", (path.name, splat)),
                    ("cameras", ("transforms.json", json.dumps(cams).encode())),
                    ("images", ("a.png", png.getvalue())),
                ],
                timeout=600,
            )
        return started, _vm_hwm_mib(proc.pid), resp.status_code, resp.text
    finally:
        proc.terminate()
        proc.wait(30)


def bombs(directory: Path) -> None:
    """Upload every bomb of `splat_bombs` to a fresh API and print the peaks (module docstring)."""
    import shutil

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from splat_bombs import BOMBS

    print(
        f"{'bomb':<18} {'file B':>8} {'HTTP':>4} {'start MiB':>9} {'peak MiB':>8} {'growth':>6} {'s':>5}  answer"
    )
    growths = []
    for name, build in BOMBS.items():
        work = Path(tempfile.mkdtemp(dir=directory, prefix=f"bench-bomb-{name}-"))
        try:
            path = build(work)
            t0 = time.perf_counter()
            started, peak, code, answer = measure_api(path, work)
            seconds = time.perf_counter() - t0
            growths.append(peak - started)
            try:
                import json

                answer = json.loads(answer).get("detail", answer)
            except ValueError:
                pass
            print(
                f"{name:<18} {path.stat().st_size:8d} {code:4d} {started:9.0f} {peak:8.0f} "
                f"{peak - started:6.0f} {seconds:5.1f}  {str(answer)[:110]}",
                flush=True,
            )
        finally:
            shutil.rmtree(work, ignore_errors=True)
    print(f"largest growth {max(growths):.0f} MiB, median {sorted(growths)[len(growths) // 2]:.0f} MiB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[100, 1000], help="file sizes in MB")
    parser.add_argument("--modes", nargs="+", default=["before", "after"], choices=["before", "after"])
    parser.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()))
    parser.add_argument("--api", action="store_true", help="measure the API process on an upload")
    parser.add_argument("--bombs", action="store_true", help="upload one hostile file per format")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(*args.child)
        return
    if args.bombs:
        bombs(args.dir)
        return
    if args.api:
        import shutil

        for size in args.sizes:
            work = Path(tempfile.mkdtemp(dir=args.dir, prefix="bench-upload-api-"))
            try:
                path = work / "splat.ply"
                write_splat(path, size)
                started, peak, code, _ = measure_api(path, work)
                print(
                    f"API: {path.stat().st_size / 1e6:.0f} MB splat -> HTTP {code}; peak RSS {started:.0f} MiB "
                    f"after start, {peak:.0f} MiB after the upload ({peak / (path.stat().st_size / 2**20):.2f}x file)",
                    flush=True,
                )
            finally:
                shutil.rmtree(work, ignore_errors=True)
        return
    base, _ = measure("none", Path("-"))
    print(f"interpreter + imports: {base:.0f} MiB peak RSS")
    print(
        f"{'file MB':>8} {'Gaussians':>10} {'mode':>7} {'peak MiB':>9} {'- base':>7} {'x file':>7} {'s':>6}"
    )
    for size in args.sizes:
        path = args.dir / f"bench-upload-{size:g}MB.ply"
        try:
            n = write_splat(path, size)
            file_mib = path.stat().st_size / 2**20
            for mode in args.modes:
                peak, seconds = measure(mode, path)
                print(
                    f"{path.stat().st_size / 1e6:8.0f} {n:10d} {mode:>7} {peak:9.0f} {peak - base:7.0f} "
                    f"{peak / file_mib:7.2f} {seconds:6.1f}",
                    flush=True,
                )
        finally:
            path.unlink(missing_ok=True)


if __name__ == "__main__":
    main()
