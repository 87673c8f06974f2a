"""What machine a timing was measured on.

Timings in reports and benchmarks are only comparable on the same CPU: on the 2-core machines this
project runs on, the shipped regressor's network took 3.4–3.7 ms per crop on one host and 6.5–7.9 ms
on another (AVX-512 vs AVX2 only), with the same code and packages. So every timing is stored with
the CPU it came from.
"""
from __future__ import annotations

import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

# instruction sets that decide how fast oneDNN/MKL run convolutions and matrix products
ISA_FLAGS = ("avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16", "amx_tile")


def _cpuinfo(path: Path = Path("/proc/cpuinfo")) -> tuple[str, set[str]]:
    """(model name, flags) of the first processor in a Linux ``/proc/cpuinfo`` ('' and an empty set
    elsewhere or when unreadable)."""
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return "", set()
    model, flags = "", set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "model name" and not model:
            model = value.strip()
        elif key in ("flags", "Features") and not flags:  # x86 / ARM
            flags = set(value.split())
        if model and flags:
            break
    return model, flags


def describe_cpu(cpuinfo: Path = Path("/proc/cpuinfo")) -> dict:
    """The CPU timings ran on: ``{"cpu_model": str, "cpus": int, "isa": [flags of ISA_FLAGS it has],
    "torch_cpu_capability": "AVX2" | "AVX512" | ... | None}`` (JSON-ready; torch's where the run loaded
    torch: a run without a network is not made to import it, ~3 s, for a label)."""
    model, flags = _cpuinfo(cpuinfo)
    torch = sys.modules.get("torch")
    try:
        capability = None if torch is None else torch.backends.cpu.get_cpu_capability()
    except AttributeError:  # torch older than 2.0
        capability = None
    return {
        "cpu_model": model or platform.processor() or platform.machine(),
        "cpus": os.cpu_count(),
        "isa": [f for f in ISA_FLAGS if f in flags],
        "torch_cpu_capability": capability,
    }


def cpu_label(record: dict) -> str:
    """One line for tables: ``"AMD EPYC, 2 CPUs, AVX2"``."""
    parts = [record.get("cpu_model") or "unknown CPU"]
    if record.get("cpus"):
        parts.append(f"{record['cpus']} CPUs")
    if record.get("torch_cpu_capability"):
        parts.append(str(record["torch_cpu_capability"]))
    return ", ".join(parts)


# the packages whose versions a result depends on (recorded beside it)
RESULT_PACKAGES = ("hybridpose", "numpy", "opencv-contrib-python-headless", "onnxruntime", "torch", "filterpy",
                   "gtsam", "mujoco")


def git_commit() -> str:
    """The short commit of the hybridpose source that runs ("unknown" outside a git checkout)."""
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def package_versions() -> dict:
    """``{"python", "machine", and each installed package of RESULT_PACKAGES: its version}``."""
    out = {"python": platform.python_version(), "machine": platform.machine()}
    for pkg in RESULT_PACKAGES:
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out
