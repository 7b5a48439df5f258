"""Find PlayCanvas `splat-transform` (npm `@playcanvas/splat-transform`) for the tests that read
exported files back with it: `$BFIELDS_SPLAT_TRANSFORM`, else the copy `.ci/run` installs under
`build/node/`, else one on PATH; and the Khronos glTF validator (npm `gltf-validator`, installed
beside it) for exported `.glb` files, which splat-transform does not read. Tests skip, saying how
to install them, when they are missing."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INSTALL = "the splat-transform stage of .ci/run: npm install --prefix build/node @playcanvas/splat-transform gltf-validator"
"""How to get it (`.ci/run` pins the version the format fixtures were made with)."""


def splat_transform() -> str:
    """Path of the splat-transform executable, or skip the test."""
    candidates = [
        os.environ.get("BFIELDS_SPLAT_TRANSFORM"),
        str(ROOT / "build" / "node" / "node_modules" / ".bin" / "splat-transform"),
        shutil.which("splat-transform"),
    ]
    for candidate in candidates:
        if candidate and Path(candidate).is_file():
            return candidate
    pytest.skip(f"splat-transform not installed (run: {INSTALL})")


GLTF_ISSUES = """
const validator = require("gltf-validator");
const bytes = new Uint8Array(require("fs").readFileSync(process.argv[1]));
validator.validateBytes(bytes).then((report) => console.log(JSON.stringify(report.issues)));
"""


def gltf_issues(path: Path) -> dict:
    """The Khronos glTF validator's `issues` report of a .glb (skips when it is not installed)."""
    modules = ROOT / "build" / "node" / "node_modules"
    node = shutil.which("node")
    if node is None or not (modules / "gltf-validator").is_dir():
        pytest.skip(f"gltf-validator not installed (run: {INSTALL})")
    done = subprocess.run(
        [node, "-e", GLTF_ISSUES, str(path)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "NODE_PATH": str(modules)},
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def convert(source: Path, target: Path) -> Path:
    """`splat-transform source target` (it picks both formats from the names); returns target."""
    done = subprocess.run(
        [splat_transform(), "-q", "-w", str(source), str(target)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr + done.stdout
    return target
