"""Build the C test FMUs of this folder: `Integrator.fmu` (FMI 2.0 CS) and
`Integrator3.fmu` (FMI 3.0 CS), plus for the FMI conformance tests
`Conformance3.fmu` (FMI 3.0 CS: feedthrough, narrow types with min/max,
arrays) and `Clocked3.fmu` (an FMI 3 scheduled-execution-only interface,
a model description without a binary).

They stand in for third-party FMUs (binary, not made with pythonfmu) in
tests/test_third_party_fmu.py and tests/test_fmi_conformance.py. Each build
compiles one C file against the FMI headers that fmpy ships (`fmpy/c-code`,
not copied here) into a shared library, fills the GUID into the
modelDescription.xml template and zips both into an .fmu.

    python tests/third_party_fmu/build.py OUT_DIR     # builds them all, prints the paths
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class FmuSource:
    model_identifier: str
    fmi_version: int  # 2 or 3
    c_file: str | None  # None: the model description alone, no binary
    template: str


FMUS = {
    2: FmuSource("Integrator", 2, "integrator2.c", "Integrator.modelDescription.xml"),
    3: FmuSource("Integrator3", 3, "integrator3.c", "Integrator3.modelDescription.xml"),
}
# the FMI conformance tests' FMUs, by model identifier
CONFORMANCE = {
    "Conformance3": FmuSource("Conformance3", 3, "conformance3.c", "Conformance3.modelDescription.xml"),
    "Clocked3": FmuSource("Clocked3", 3, None, "Clocked3.modelDescription.xml"),
}


class BuildError(RuntimeError):
    """The compiler failed; the message holds its command line and output."""


def c_code_dir() -> Path:
    """fmpy's copy of the FMI 1/2/3 headers."""
    import fmpy

    path = Path(fmpy.__file__).parent / "c-code"
    if not (path / "fmi2Functions.h").is_file() or not (path / "fmi3Functions.h").is_file():
        raise BuildError(f"fmpy has no FMI headers in {path}")
    return path


def compiler() -> str | None:
    """The C compiler to use (`CC`, else gcc), or None when there is none."""
    return shutil.which(os.environ.get("CC", "gcc"))


def _binary_dir(fmi_version: int) -> str:
    import fmpy

    # FMI 2 names platforms like "linux64", FMI 3 uses tuples like "x86_64-linux"
    return fmpy.platform if fmi_version == 2 else fmpy.platform_tuple


def guid_for(src: FmuSource) -> str:
    """A GUID that changes whenever the C source or the model description template changes."""
    text = (HERE / src.c_file).read_bytes() if src.c_file else b""
    text += (HERE / src.template).read_bytes()
    return "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, f"v2i-cosim-test-fmu:{text.hex()}")) + "}"


def build_fmu(fmi_version: int | FmuSource, out_dir: Path, cc: str | None = None) -> Path:
    """Compile and package one test FMU (by FMI version, or an FmuSource) into `out_dir`; returns the .fmu path."""
    import fmpy

    src = fmi_version if isinstance(fmi_version, FmuSource) else FMUS[fmi_version]
    if src.c_file is None:
        return _package_description(src, Path(out_dir))
    cc = cc or compiler()
    if cc is None:
        raise BuildError("no C compiler found (set CC or install gcc)")
    out_dir = Path(out_dir)
    work = out_dir / f"{src.model_identifier}.build"
    if work.exists():
        shutil.rmtree(work)
    binary_rel = f"binaries/{_binary_dir(fmi_version)}/{src.model_identifier}{fmpy.sharedLibraryExtension}"
    binary = work / binary_rel
    binary.parent.mkdir(parents=True)
    guid = guid_for(src)

    cmd = [cc, "-shared", "-fPIC", "-std=c99", "-O2", "-Wall", "-Wextra", "-fvisibility=hidden",
           f"-I{c_code_dir()}", f'-DMODEL_GUID="{guid}"',
           "-o", str(binary), str(HERE / src.c_file), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"compiling {src.c_file} failed ({proc.returncode}):\n  {' '.join(cmd)}\n"
                         f"{proc.stdout}{proc.stderr}")
    if proc.stderr.strip():  # warnings (none with gcc 12): shown, not fatal
        print(f"warnings compiling {src.c_file}:\n{proc.stderr}", file=sys.stderr)

    model_description = (HERE / src.template).read_text().replace("@GUID@", guid)
    fmu = out_dir / f"{src.model_identifier}.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("modelDescription.xml", model_description)
        zf.write(binary, binary_rel)
    shutil.rmtree(work)
    return fmu


def _package_description(src: FmuSource, out_dir: Path) -> Path:
    """An .fmu holding only the filled-in model description (for interfaces the master refuses unread)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    fmu = out_dir / f"{src.model_identifier}.fmu"
    with zipfile.ZipFile(fmu, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("modelDescription.xml", (HERE / src.template).read_text().replace("@GUID@", guid_for(src)))
    return fmu


def build_all(out_dir: Path, cc: str | None = None) -> dict[int, Path]:
    """Both Integrator FMUs, keyed by FMI major version."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return {version: build_fmu(version, out_dir, cc) for version in FMUS}


def build_conformance(out_dir: Path, cc: str | None = None) -> dict[str, Path]:
    """The conformance tests' FMUs, keyed by model identifier."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return {name: build_fmu(src, out_dir, cc) for name, src in CONFORMANCE.items()}


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(f"usage: {sys.argv[0]} OUT_DIR")
    for path in [*build_all(Path(sys.argv[1])).values(), *build_conformance(Path(sys.argv[1])).values()]:
        print(path)
