"""The machine's checks: Python, torch, the pinned packages, free disk, the optional tools of the tests.

The pins are read from vlaprobe's installed metadata (``pyproject.toml``'s dependencies and its ``libero``
extra, which ``scripts/setup.sh`` installs with ``--no-deps``): one source, no second copy of the numbers.
"""

from __future__ import annotations

import platform
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import InvalidVersion, Version

from vlaprobe.configs.doctor import DoctorConfig
from vlaprobe.doctor.report import SETUP_FIX, Check
from vlaprobe.errors import VlaprobeError
from vlaprobe.files import JsonObject

PINNED = ("mujoco", "robosuite", "libero", "bddl", "transformers")
"""Packages checked one line each: the simulator stack (contact dynamics and renders differ between releases) and
transformers (versions before 4.48 change OpenVLA's decoder)."""


def requirements() -> tuple[list[Requirement], list[Requirement]]:
    """vlaprobe's requirements and its ``libero`` extra's, from the installed package's metadata."""
    try:
        lines = metadata.requires("vlaprobe") or []
    except metadata.PackageNotFoundError:
        raise VlaprobeError(f"vlaprobe's package metadata is not installed; {SETUP_FIX}") from None
    base, libero = [], []
    for req in map(Requirement, lines):
        if req.marker is None or req.marker.evaluate({"extra": ""}):
            base.append(req)
        elif req.marker.evaluate({"extra": "libero"}):
            libero.append(req)
    return base, libero


def installed(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def satisfied(req: Requirement, version: str | None) -> bool:
    if version is None:
        return False
    try:
        return req.specifier.contains(Version(version), prereleases=True)
    except InvalidVersion:
        return False


def python_check() -> Check:
    """The interpreter against ``Requires-Python``."""
    wanted = metadata.metadata("vlaprobe")["Requires-Python"] or ""
    version = platform.python_version()
    summary = f"{version} ({sys.executable})"
    if wanted and not Requirement(f"python{wanted}").specifier.contains(version):
        return Check(
            "python",
            "fail",
            f"{summary} does not satisfy {wanted}",
            f"use Python {wanted}: PYTHON=... {SETUP_FIX}",
        )
    return Check("python", "ok", f"{summary}; vlaprobe needs {wanted}", figures={"version": version})


def pin_checks() -> list[Check]:
    """One line per package of :data:`PINNED`, and one for every other requirement together."""
    base, libero = requirements()
    by_name = {canonicalize_name(r.name): r for r in [*base, *libero]}
    checks = []
    for name in PINNED:
        req = by_name.get(canonicalize_name(name))
        version = installed(name)
        if req is None:
            checks.append(
                Check(
                    f"version.{name}",
                    "fail",
                    f"vlaprobe's installed metadata names no requirement for {name}: it predates this checkout",
                    SETUP_FIX,
                )
            )
            continue
        pin = f"{req.name}{req.specifier}"  # without the extra's marker
        figures = {"installed": version, "pin": pin}
        if satisfied(req, version):
            checks.append(Check(f"version.{name}", "ok", f"{version} (pin {req.specifier})", figures=figures))
            continue
        install = f"pip install {'--no-deps ' if req in libero else ''}'{pin}'"
        summary = f"{version or 'not installed'}, needs {req.specifier}"
        checks.append(
            Check(f"version.{name}", "fail", summary, f"{install}, or {SETUP_FIX}", figures=figures)
        )
    others = [r for r in base if canonicalize_name(r.name) not in {*PINNED, "torch"}]
    bad = [
        f"{r.name} {installed(r.name) or 'missing'} (needs {r.specifier})"
        for r in others
        if not satisfied(r, installed(r.name))
    ]
    if bad:
        checks.append(Check("requirements", "fail", f"{len(bad)} unmet: {', '.join(bad[:4])}", SETUP_FIX))
    else:
        checks.append(Check("requirements", "ok", f"the {len(others)} other requirements are met"))
    return checks


def torch_check(cfg: DoctorConfig) -> Check:
    """torch's version and build, the device and dtype a run would use (``--device``), bf16 on a GPU."""
    import torch

    from vlaprobe.policies.openvla.policy import device_and_dtype

    base, _ = requirements()
    req = next((r for r in base if r.name == "torch"), None)
    version = torch.__version__
    cuda = torch.version.cuda
    figures: JsonObject = {
        "version": version,
        "cuda_build": cuda,
        "cuda_available": torch.cuda.is_available(),
    }
    build = f"CUDA {cuda} build" if cuda else "CPU build"
    if req is not None and not satisfied(req, version):
        return Check(
            "torch", "fail", f"{version} ({build}), needs {req.specifier}", SETUP_FIX, figures=figures
        )
    dev, dtype = device_and_dtype(cfg.policy.device)
    runs = f"--device {cfg.policy.device} runs on {dev} in {str(dtype).removeprefix('torch.')}"
    if dev.type == "cuda":
        name = torch.cuda.get_device_name(dev)
        bf16 = torch.cuda.is_bf16_supported()
        figures |= {"gpu": name, "gpus": torch.cuda.device_count(), "bf16": bf16}
        if not bf16:
            return Check(
                "torch", "fail", f"{version} ({build}) on {name}: no bfloat16, which the GPU path uses",
                "use a GPU with bfloat16 (Ampere or later) or --device cpu", figures=figures,
            )  # fmt: skip
        return Check("torch", "ok", f"{version} ({build}), {name}, bf16 supported; {runs}", figures=figures)
    if cuda is None and shutil.which("nvidia-smi"):
        return Check(
            "torch", "warn", f"{version} ({build}) but an NVIDIA driver is present; {runs}",
            "reinstall torch from the CUDA index to use the GPU", figures=figures,
        )  # fmt: skip
    return Check("torch", "ok", f"{version} ({build}); {runs}", figures=figures)


HIDDEN_STORED = 0.89
"""Stored/raw size of float16 hidden states (zstd; docs/collection.md, measured on an expert episode)."""
IMAGE_STORED = 0.19
"""Stored/raw size of the 224² model image (16-19% measured; the upper end)."""
OTHER_BYTES = 3000
"""Atoms, actions, proprioception and the world snapshot of one row, stored (the snapshot: ~1.5 KB raw)."""


def row_bytes(num_hidden_states: int, hidden_size: int, pooling: str) -> int:
    """The stored size of one step of an activation store (estimated from the measured compression)."""
    positions = 7 if pooling == "action_tokens" else 1
    hidden = num_hidden_states * hidden_size * positions * 2 * HIDDEN_STORED
    return int(hidden + 224 * 224 * 3 * IMAGE_STORED + OTHER_BYTES)


def disk_check(cfg: DoctorConfig, dims: tuple[int, int] | None) -> Check:
    """Free disk where ``--out`` is (or would be) against the run's stores, at most ``--env.max-steps`` rows per
    episode; ``dims`` (hidden states, hidden size) come from the loaded model."""
    folder = Path(cfg.out).resolve()
    while not folder.exists():
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    figures: JsonObject = {"folder": str(folder), "free_bytes": free}
    if dims is None:
        return Check(
            "disk",
            "warn",
            f"{free / 1e9:.1f} GB free at {folder}; the store's size needs the model",
            "fix the policy check",
            figures=figures,
        )
    stores = 2 if cfg.control else 1
    per_row = row_bytes(*dims, cfg.policy.pooling)
    need = cfg.episodes * stores * cfg.env.max_steps * per_row
    figures |= {"need_bytes": need, "row_bytes": per_row}
    summary = (
        f"{free / 1e9:.1f} GB free at {folder}; the run's store{'s' * (stores > 1)} take at most "
        f"{need / 1e9:.2f} GB ({cfg.episodes} episodes x {stores} x <= {cfg.env.max_steps} steps x {per_row / 1e3:.0f} KB)"
    )
    if free < need:
        return Check(
            "disk",
            "fail",
            summary,
            f"free {(need - free) / 1e9:.1f} GB or choose --out on another disk",
            figures=figures,
        )
    return Check("disk", "ok", summary, figures=figures)


CHROMIUM = Path("/usr/bin/chromium")
"""The browser the web UI's end-to-end test drives (Playwright with Debian's chromium)."""


def chromium_check() -> Check:
    """The browser of the web UI's end-to-end test (a warning when missing: only that test needs it)."""
    if not CHROMIUM.is_file():
        return Check(
            "chromium", "warn", f"no {CHROMIUM}: the browser test is skipped", "apt install chromium"
        )
    try:
        done = subprocess.run([str(CHROMIUM), "--version"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return Check(
            "chromium",
            "warn",
            f"{CHROMIUM} does not start ({type(exc).__name__})",
            "apt install --reinstall chromium",
        )
    return Check("chromium", "ok", f"{done.stdout.strip() or CHROMIUM}; the browser test runs")


TOOLS = (
    ("prolog", "swipl", "the Prolog twin of the consistency rules is not tested", "swi-prolog-nox"),
    ("compiler", "g++", "`vlaprobe finetune --compile` and its test cannot build kernels", "g++"),
)
"""(check name, program, what is lost without it, Debian package): tools only tests and options use."""


def tool_check(name: str, tool: str, lost: str, package: str) -> Check:
    found = shutil.which(tool)
    if found:
        return Check(name, "ok", f"{tool} at {found}")
    return Check(name, "warn", f"no {tool}: {lost}", f"apt install {package}")
