"""export/cpp as a CMake package: its ctest suite passes, it installs, and a separate project
finds the installed copy with ``find_package(slimseg_consumer CONFIG)`` and links
``slimseg::consumer``.

One build (Release, unity, ``-j 2``) into a temporary folder, ``cmake --install`` into a
temporary prefix, then a consumer project written here (a CMakeLists and a ``main.cpp`` that
includes ``<slimseg/consumer.hpp>``) configured against that prefix only.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest
from conftest import have_cpp_toolchain

from slimseg import __version__

ROOT = Path(__file__).resolve().parents[2]
# CMake versions are numeric: export/cpp takes __version__'s leading x.y.z (0.2.0rc1 -> 0.2.0)
VERSION = re.match(r"[0-9]+(\.[0-9]+)*", __version__).group()

pytestmark = pytest.mark.skipif(not have_cpp_toolchain(), reason="needs cmake and a C++ compiler")

# The consumer project: the installed package (find_package, slimseg::consumer) or, given
# SLIMSEG_SOURCE, export/cpp itself (add_subdirectory, the plain target name).
CONSUMER_CMAKE = """\
cmake_minimum_required(VERSION 3.14)
project(uses_slimseg LANGUAGES CXX)
add_executable(uses_slimseg main.cpp)
if(SLIMSEG_SOURCE)
    add_subdirectory(${SLIMSEG_SOURCE} slimseg_consumer)
    target_link_libraries(uses_slimseg PRIVATE slimseg_consumer)
else()
    find_package(slimseg_consumer ${WANT} CONFIG REQUIRED)
    target_link_libraries(uses_slimseg PRIVATE slimseg::consumer)
    target_compile_definitions(uses_slimseg PRIVATE
        FOUND_VERSION="${slimseg_consumer_VERSION}")
endif()
"""

# A 480 x 640 frame into a 384 x 640 input: scale 0.8, 512 x 384 resized, 64 px on each side.
CONSUMER_MAIN = r"""
#include <slimseg/consumer.hpp>

#include <cstdio>

int main() {
    const slimseg::Letterbox lb = slimseg::letterbox_params(480, 640, 384, 640);
    std::printf("letterbox %.3f %d %d %d %d\n", lb.scale, lb.new_w, lb.new_h, lb.left, lb.top);
    std::printf("half %04x %04x\n", slimseg::float_to_half(1.0f), slimseg::float_to_half(-2.5f));
    const slimseg::Metadata meta = slimseg::Metadata::from_json(
        R"({"names": ["person", "chair"], "imgsz": [384, 640], "family": "yolov8",
            "task": "detect", "mobility": [1.0, 0.1]})");
    std::printf("metadata %d %d %d %.1f\n", meta.num_classes(), meta.input_h, meta.input_w,
                meta.mobility[1]);
    try {
        slimseg::Metadata::from_json(R"({"names": ["person"], "imgsz": [384, 640]})");
        std::printf("no error\n");
    } catch (const slimseg::Error& e) {
        std::printf("error %s\n", e.what());
    }
#ifdef FOUND_VERSION
    std::printf("version %s\n", FOUND_VERSION);
#endif
    return 0;
}
"""


def _run(cmd: list[str], cwd: Path | None = None) -> str:
    """Run ``cmd``; on failure the assertion shows its output."""
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    assert done.returncode == 0, f"{' '.join(cmd)}\n{done.stdout}\n{done.stderr}"
    return done.stdout


def _configure(src: Path, build: Path, *defs: str) -> subprocess.CompletedProcess:
    cmd = ["cmake", "-S", str(src), "-B", str(build), "-DCMAKE_BUILD_TYPE=Release", *defs]
    return subprocess.run(cmd, capture_output=True, text=True)


EXPECTED = [
    "letterbox 0.800 512 384 64 0",
    "half 3c00 c100",
    "metadata 2 384 640 0.1",
    "error metadata family: missing (not a slimseg export? re-export with slimseg export)",
]


def _consumer(tmp_path: Path, name: str, *defs: str) -> subprocess.CompletedProcess:
    """Configure the consumer project (written under ``tmp_path/app``) into ``tmp_path/name``."""
    app = tmp_path / "app"
    app.mkdir(exist_ok=True)
    (app / "CMakeLists.txt").write_text(CONSUMER_CMAKE)
    (app / "main.cpp").write_text(CONSUMER_MAIN)
    return _configure(app, tmp_path / name, *defs)


def test_cpp_package_builds_tests_installs_and_is_found(tmp_path: Path) -> None:
    build, prefix = tmp_path / "build", tmp_path / "prefix"
    done = _configure(ROOT / "export" / "cpp", build, "-DCMAKE_UNITY_BUILD=ON",
                      "-DSLIMSEG_TESTS=ON", "-DSLIMSEG_EXAMPLES=ON")  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    _run(["cmake", "--build", str(build), "-j", "2"])
    ctest = _run(["ctest", "--output-on-failure", "--no-tests=error", "-j", "2"], cwd=build)
    assert re.search(r"100% tests passed, 0 tests failed out of [1-9]", ctest), ctest
    _run(["cmake", "--install", str(build), "--prefix", str(prefix)])

    assert (prefix / "include" / "slimseg" / "consumer.hpp").is_file()
    assert (prefix / "include" / "slimseg" / "rules.hpp").is_file()
    assert (prefix / "bin" / "slimseg_masks").is_file()
    configs = list(prefix.glob("lib*/cmake/slimseg_consumer/slimseg_consumerConfigVersion.cmake"))
    assert len(configs) == 1, sorted(p.relative_to(prefix) for p in prefix.rglob("*"))
    assert f'set(PACKAGE_VERSION "{VERSION}")' in configs[0].read_text()

    # only the prefix is searched (not the user's package registry)
    found = [f"-DCMAKE_PREFIX_PATH={prefix}", "-DCMAKE_FIND_PACKAGE_NO_PACKAGE_REGISTRY=ON"]
    done = _consumer(tmp_path, "app_build", *found, f"-DWANT={VERSION}")
    assert done.returncode == 0, done.stdout + done.stderr
    _run(["cmake", "--build", str(tmp_path / "app_build"), "-j", "2"])
    out = _run([str(tmp_path / "app_build" / "uses_slimseg")]).splitlines()
    assert out == [*EXPECTED, f"version {VERSION}"]

    # the version file is what find_package checks: a later major version is refused
    done = _consumer(tmp_path, "app_build_99", *found, "-DWANT=99.0")
    assert done.returncode != 0
    assert "slimseg_consumer" in done.stderr and VERSION in done.stderr, done.stderr


def test_cpp_add_subdirectory_keeps_the_plain_target_name(tmp_path: Path) -> None:
    source = ROOT / "export" / "cpp"
    done = _consumer(tmp_path, "app_build", f"-DSLIMSEG_SOURCE={source}", "-DCMAKE_UNITY_BUILD=ON")
    assert done.returncode == 0, done.stdout + done.stderr
    _run(["cmake", "--build", str(tmp_path / "app_build"), "-j", "2"])
    out = _run([str(tmp_path / "app_build" / "uses_slimseg")]).splitlines()
    assert out == EXPECTED
    # a subproject builds the library only: no example, no tests, no install rules
    sub = tmp_path / "app_build" / "slimseg_consumer"
    assert any(sub.glob("*slimseg_consumer*"))
    assert not (sub / "slimseg_masks").exists() and not (sub / "tests").exists()
    assert "file(INSTALL" not in (sub / "cmake_install.cmake").read_text()
