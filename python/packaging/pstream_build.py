"""ParticleStream's PEP 517 build backend: `pip install .` without anything from PyPI.

It builds the `particlestream_python` target with CMake (Ninja, Release) in a build folder and
packs the module and its type stubs into a wheel for the running interpreter. Settings
(`pip install --config-settings KEY=VALUE .`):

    build-dir=PATH   the CMake build folder (default: build-wheel/ in the source tree); an
                     existing configured build (such as scripts/build.sh's build/) is reused and
                     only brought up to date
    jobs=N           parallel compile jobs (default: the CPU count)

Only the standard library is used, so pip's isolated build environment needs no packages.
"""
import base64
import hashlib
import os
import pathlib
import re
import subprocess
import sys
import sysconfig
import zipfile

ROOT = pathlib.Path(__file__).resolve().parents[2]
NAME = "particlestream"


def _version():
    text = (ROOT / "CMakeLists.txt").read_text()
    match = re.search(r"project\(\s*ParticleStream\s+VERSION\s+([0-9.]+)", text)
    if not match:
        raise RuntimeError(f"{ROOT / 'CMakeLists.txt'}: no `project(ParticleStream VERSION x.y.z)` found")
    return match.group(1)


def _tag():
    impl = f"cp{sys.version_info.major}{sys.version_info.minor}"
    platform = sysconfig.get_platform().replace("-", "_").replace(".", "_")
    return f"{impl}-{impl}-{platform}"


def _metadata():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    return (
        "Metadata-Version: 2.1\n"
        f"Name: {NAME}\n"
        f"Version: {_version()}\n"
        "Summary: Read Alembic point caches, cook them into .pstream clips and play them back\n"
        "Requires-Python: >=3.9\n"
        "Requires-Dist: numpy\n"
        "Description-Content-Type: text/markdown\n"
        "\n" + readme)


def _dist_info():
    return f"{NAME}-{_version()}.dist-info"


def _setting(config_settings, key, default):
    value = (config_settings or {}).get(key)
    return default if value in (None, "") else value


def _run(command):
    print("pstream_build:", " ".join(str(c) for c in command), file=sys.stderr, flush=True)
    subprocess.run([str(c) for c in command], check=True, cwd=ROOT)


def _build_module(config_settings):
    build = pathlib.Path(_setting(config_settings, "build-dir", ROOT / "build-wheel"))
    if not build.is_absolute():
        build = ROOT / build
    jobs = str(_setting(config_settings, "jobs", os.cpu_count() or 1))
    if not (build / "CMakeCache.txt").exists():
        _run(["cmake", "-S", ROOT, "-B", build, "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release", "-DPSTREAM_BENCH=OFF",
              "-DPSTREAM_TESTS=OFF", f"-DPython3_EXECUTABLE={sys.executable}"])
    _run(["cmake", "--build", build, "--target", "particlestream_python", "-j", jobs])
    suffix = sysconfig.get_config_var("EXT_SUFFIX")
    module = build / "python" / f"{NAME}{suffix}"
    if not module.exists():
        found = sorted((build / "python").glob(f"{NAME}.*.so"))
        raise RuntimeError(f"{build / 'python'}: no {NAME}{suffix} after the build"
                           + (f" (found {', '.join(p.name for p in found)}: that build is for another Python; "
                              "use a build-dir configured for this one)" if found else ""))
    return module


def _record_line(path, data):
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{path},sha256={digest},{len(data)}"


def get_requires_for_build_wheel(config_settings=None):
    return []


def get_requires_for_build_editable(config_settings=None):
    return []


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    info = pathlib.Path(metadata_directory) / _dist_info()
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(_metadata(), encoding="utf-8")
    return info.name


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    module = _build_module(config_settings)
    files = {
        module.name: module.read_bytes(),
        f"{NAME}.pyi": (ROOT / "python" / f"{NAME}.pyi").read_bytes(),
        f"{_dist_info()}/METADATA": _metadata().encode(),
        f"{_dist_info()}/WHEEL": (f"Wheel-Version: 1.0\nGenerator: pstream_build\nRoot-Is-Purelib: false\n"
                                  f"Tag: {_tag()}\n").encode(),
        f"{_dist_info()}/top_level.txt": f"{NAME}\n".encode(),
    }
    record = f"{_dist_info()}/RECORD"
    lines = [_record_line(path, data) for path, data in files.items()] + [f"{record},,"]
    files[record] = ("\n".join(lines) + "\n").encode()
    wheel = pathlib.Path(wheel_directory) / f"{NAME}-{_version()}-{_tag()}.whl"
    partial = wheel.with_suffix(".partial")
    try:
        with zipfile.ZipFile(partial, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for path, data in files.items():
                info = zipfile.ZipInfo(path, date_time=(2020, 1, 1, 0, 0, 0))
                info.external_attr = (0o755 if path.endswith(".so") else 0o644) << 16
                info.compress_type = zipfile.ZIP_DEFLATED
                z.writestr(info, data)
        os.replace(partial, wheel)
    finally:
        partial.unlink(missing_ok=True)
    return wheel.name


def build_sdist(sdist_directory, config_settings=None):
    raise RuntimeError("pstream_build makes wheels only: install from the repository (`pip install .`)")
