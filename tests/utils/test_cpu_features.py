"""The CPU-feature parser behind ``slimseg bench``'s CPU line, on canned /proc/cpuinfo texts."""

from __future__ import annotations

from pathlib import Path

from slimseg.utils.cpu_features import detect_cpu_features, parse_cpuinfo

X86_HEAD = "processor\t: 0\nvendor_id\t: {vendor}\nmodel name\t: {model}\n"
AVX2_ONLY = "fpu vme sse sse2 ssse3 sse4_1 sse4_2 avx f16c fma avx2 bmi1 bmi2"
ZEN4 = AVX2_ONLY + " avx512f avx512dq avx512bw avx512vl avx512_bf16 avx512_vnni gfni vaes"
SAPPHIRE = ZEN4 + " avx_vnni amx_bf16 amx_tile amx_int8"
ARM_HEAD = "processor\t: 0\nBogoMIPS\t: 48.00\nCPU implementer\t: 0x41\nCPU part\t: 0xd0c\n"


def _x86(flags: str, model: str = "AMD EPYC 7B13", vendor: str = "AuthenticAMD") -> str:
    # two processors: only the first one is read
    one = X86_HEAD.format(vendor=vendor, model=model) + f"flags\t\t: {flags}\n"
    return one + "\n" + one.replace("processor\t: 0", "processor\t: 1")


def test_x86_without_vnni() -> None:
    cpu = parse_cpuinfo(_x86(AVX2_ONLY))
    assert (cpu.arch, cpu.model, cpu.int8, cpu.known) == ("x86_64", "AMD EPYC 7B13", ["AVX2"], True)
    assert cpu.dot_product is False
    assert "no 8-bit dot product" in cpu.describe() and "AVX2" in cpu.describe()


def test_x86_with_avx512_vnni_and_old_flag_name() -> None:
    cpu = parse_cpuinfo(_x86(ZEN4, "AMD EPYC 9R14"))
    assert cpu.int8 == ["AVX2", "AVX-512F", "AVX-512BW", "AVX-512 VNNI"] and cpu.dot_product
    assert "8-bit dot product present" in cpu.describe()
    # kernels before 4.x spelled it avx512vnni: the same name, listed once
    old = parse_cpuinfo(_x86(AVX2_ONLY + " avx512f avx512vnni avx512_vnni"))
    assert old.int8 == ["AVX2", "AVX-512F", "AVX-512 VNNI"]


def test_x86_with_avx_vnni_and_amx() -> None:
    cpu = parse_cpuinfo(_x86(SAPPHIRE, "Intel(R) Xeon(R) Platinum 8488C", "GenuineIntel"))
    assert cpu.int8[-3:] == ["AVX-512 VNNI", "AVX-VNNI", "AMX-INT8"] and cpu.dot_product


def test_arm_with_and_without_dot_product() -> None:
    dot = parse_cpuinfo(ARM_HEAD + "Features\t: fp asimd evtstrm aes crc32 asimddp i8mm sve\n")
    assert (dot.arch, dot.model) == ("arm64", "part 0xd0c")
    assert dot.int8 == ["NEON", "dot product", "i8mm", "SVE"] and dot.dot_product
    a72 = parse_cpuinfo(ARM_HEAD + "Features\t: fp asimd evtstrm crc32 cpuid\n")
    assert a72.int8 == ["NEON"] and a72.dot_product is False
    assert "no 8-bit dot product" in a72.describe()


def test_unknown_when_nothing_to_read(tmp_path: Path) -> None:
    blank = parse_cpuinfo("", arch="AMD64")
    assert (blank.arch, blank.known, blank.dot_product) == ("x86_64", False, None)
    assert "unknown" in blank.describe()
    missing = detect_cpu_features(tmp_path / "no-cpuinfo")
    assert missing.known is False and "unknown" in missing.describe()
