"""The CPU's integer dot-product instruction sets, the ones that decide onnxruntime's INT8 speed.

onnxruntime's CPU INT8 kernels (MLAS) pick a code path by what the CPU offers: on x86, AVX2
(``vpmaddubsw``: unsigned 8-bit activations times signed 8-bit weights, U8S8), AVX-512
(``avx512bw``), AVX-512 VNNI or AVX-VNNI (``vpdpbusd``: U8S8 in one instruction) and AMX
(``amx_int8`` tiles); on ARM64 the dot-product (``asimddp``: ``sdot``/``udot``) and the int8
matrix-multiply (``i8mm``) extensions. :func:`detect_cpu_features` reads them from
``/proc/cpuinfo`` on Linux (x86 ``flags``, ARM ``Features``); elsewhere it says "unknown".
"""

from __future__ import annotations

import logging
import platform
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

CPUINFO = Path("/proc/cpuinfo")
# cpuinfo flag -> the name printed, in the order printed (x86, then ARM).
X86_INT8_FLAGS = {
    "avx2": "AVX2",
    "avx512f": "AVX-512F",
    "avx512bw": "AVX-512BW",
    "avx512_vnni": "AVX-512 VNNI",
    "avx512vnni": "AVX-512 VNNI",  # older kernels
    "avx_vnni": "AVX-VNNI",
    "amx_int8": "AMX-INT8",
}
ARM_INT8_FLAGS = {"asimd": "NEON", "asimddp": "dot product", "i8mm": "i8mm", "sve": "SVE"}
# Names meaning "this CPU has a fused 8-bit dot product" (what fast INT8 needs).
DOT_PRODUCT = ("AVX-512 VNNI", "AVX-VNNI", "AMX-INT8", "dot product", "i8mm")


@dataclass
class CpuFeatures:
    """``arch``: ``x86_64``, ``arm64`` or what the platform says; ``model``: the CPU's name
    (``""`` when unknown); ``int8``: the INT8-relevant instruction sets found, in a fixed
    order; ``known``: whether they were read at all (``False``: not Linux, or unreadable)."""

    arch: str
    model: str = ""
    int8: list[str] = field(default_factory=list)
    known: bool = True

    @property
    def dot_product(self) -> bool | None:
        """Whether an 8-bit dot-product instruction is there; ``None`` when unknown."""
        return any(f in DOT_PRODUCT for f in self.int8) if self.known else None

    def describe(self) -> str:
        """One line for a report, e.g. ``x86_64 AMD EPYC 9R14: AVX2, AVX-512 VNNI (...)``."""
        name = f"{self.arch} {self.model}".strip()
        if not self.known:
            return f"{name}: instruction sets unknown (no /proc/cpuinfo)"
        found = ", ".join(self.int8) or "none of AVX2/AVX-512/VNNI/AMX/NEON dot product"
        if self.dot_product:
            note = "8-bit dot product present: U8S8 INT8 can beat FP32"
        elif "AVX2" in self.int8 or "NEON" in self.int8:
            note = "no 8-bit dot product: INT8 gains less over FP32"
        else:
            note = "no SIMD INT8 path found"
        return f"{name}: {found} ({note})"

    def as_dict(self) -> dict[str, object]:
        return {"arch": self.arch, "model": self.model, "int8": self.int8, "known": self.known}


def _normalise_arch(machine: str) -> str:
    m = machine.lower()
    if m in ("x86_64", "amd64"):
        return "x86_64"
    if m in ("aarch64", "arm64"):
        return "arm64"
    return m or "unknown"


def parse_cpuinfo(text: str, arch: str = "") -> CpuFeatures:
    """The :class:`CpuFeatures` a ``/proc/cpuinfo`` text declares (its first processor).

    x86 lists instruction sets under ``flags``, ARM under ``Features``; ``arch`` (optional)
    is used only when the text does not say which it is.
    """
    flags: set[str] = set()
    model = ""
    kind = ""
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if not sep:
            continue
        key = key.strip().lower()
        if key == "flags" and not flags:
            flags, kind = set(value.split()), "x86_64"
        elif key == "features" and not flags:
            flags, kind = set(value.split()), "arm64"
        elif key == "model name" and not model:
            model = value.strip()
        elif key == "cpu part" and not model:
            model = f"part {value.strip()}"
    arch = kind or _normalise_arch(arch)
    if not flags:
        return CpuFeatures(arch, model, [], known=False)
    table = X86_INT8_FLAGS if arch == "x86_64" else ARM_INT8_FLAGS
    found: list[str] = []
    for flag, name in table.items():
        if flag in flags and name not in found:
            found.append(name)
    return CpuFeatures(arch, model, found)


def detect_cpu_features(cpuinfo: Path = CPUINFO) -> CpuFeatures:
    """This machine's :class:`CpuFeatures` (``known=False`` where ``cpuinfo`` is unreadable)."""
    arch = _normalise_arch(platform.machine())
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError as exc:
        log.debug("cpu features: %s unreadable (%s)", cpuinfo, exc)
        return CpuFeatures(arch, platform.processor(), [], known=False)
    return parse_cpuinfo(text, arch)
