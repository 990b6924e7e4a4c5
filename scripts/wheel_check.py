"""Does a Linux wheel run on the glibc it promises? (`make wheel-check`, and its test in `make test`)

Reads a wheel's platform tags (from its file name and from the ``Tag:`` lines of its
``*.dist-info/WHEEL``) and, in every ELF file it holds, the highest ``GLIBC_x.y`` symbol version
the file requires (its ``.gnu.version_r`` section: what the dynamic loader checks at start-up).
Fails (exit 1) if a tag names a newer glibc than ``--max-glibc``, if a binary requires one, or if
the wheel holds no ELF file at all (nothing was checked). A ``linux_*`` tag (no manylinux
promise) fails too: pip installs such a wheel only on the machine that built it.

    python scripts/wheel_check.py dist/sharedspace_server-*.whl --max-glibc 2.17

It needs pyelftools (auditwheel's dependency, in clients/requirements-dev.txt); it reads the
wheel, it does not install it.
"""

from __future__ import annotations

import argparse
import io
import re
import sys
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

from elftools.common.exceptions import ELFError
from elftools.elf.elffile import ELFFile
from elftools.elf.gnuversions import GNUVerNeedSection

# PEP 600's names, and the legacy aliases of PEP 513/571/599 (glibc 2.5, 2.12, 2.17).
MANYLINUX_TAG = re.compile(r"^manylinux_(\d+)_(\d+)_\w+$")
LEGACY_TAGS = {"manylinux1": (2, 5), "manylinux2010": (2, 12), "manylinux2014": (2, 17)}
GLIBC_VERSION = re.compile(r"^GLIBC_(\d+)\.(\d+)(?:\.\d+)?$")


class WheelCheckError(Exception):
    """The wheel cannot be checked: not a zip, no platform tag."""


@dataclass
class WheelReport:
    """What a wheel promises (its platform tags) and what its binaries need."""

    wheel: str
    tags: list[str]
    # each tag's glibc (major, minor), or None for a tag that promises no glibc (linux_x86_64)
    tag_glibc: dict[str, tuple[int, int] | None]
    # ELF file in the wheel -> (highest GLIBC_ version it requires, the symbol version's name)
    binaries: dict[str, tuple[tuple[int, int], str] | None] = field(
        default_factory=dict
    )

    def problems(self, max_glibc: tuple[int, int]) -> list[str]:
        """Why the wheel breaks the promise of ``max_glibc``: empty when it keeps it."""
        out = []
        for tag, glibc in self.tag_glibc.items():
            if glibc is None:
                out.append(
                    f"platform tag {tag!r} promises no glibc (not a manylinux tag)"
                )
            elif glibc > max_glibc:
                out.append(
                    f"platform tag {tag!r} needs glibc {fmt(glibc)} > {fmt(max_glibc)}"
                )
        if not self.binaries:
            out.append("the wheel holds no ELF binary: nothing to check")
        for name, need in self.binaries.items():
            if need is not None and need[0] > max_glibc:
                out.append(f"{name} requires {need[1]} > GLIBC_{fmt(max_glibc)}")
        return out


def fmt(version: tuple[int, int]) -> str:
    return f"{version[0]}.{version[1]}"


def parse_glibc(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"(\d+)\.(\d+)", text)
    if not match:
        raise argparse.ArgumentTypeError(
            f"a glibc version is MAJOR.MINOR, like 2.17: {text!r}"
        )
    return int(match[1]), int(match[2])


def tag_glibc(tag: str) -> tuple[int, int] | None:
    """The glibc a platform tag promises to need at most; None for a non-manylinux tag."""
    for legacy, version in LEGACY_TAGS.items():
        if tag.startswith(legacy + "_"):
            return version
    match = MANYLINUX_TAG.match(tag)
    return (int(match[1]), int(match[2])) if match else None


def highest_glibc(elf: ELFFile) -> tuple[tuple[int, int], str] | None:
    """The highest ``GLIBC_x.y`` in the file's version-needs section, or None if it needs none."""
    best = None
    for section in elf.iter_sections():
        if not isinstance(section, GNUVerNeedSection):
            continue
        for _needed, auxiliaries in section.iter_versions():
            for aux in auxiliaries:
                match = GLIBC_VERSION.match(aux.name)
                if match:
                    version = (int(match[1]), int(match[2]))
                    if best is None or version > best[0]:
                        best = (version, aux.name)
    return best


def platform_tags(wheel: Path, archive: zipfile.ZipFile) -> list[str]:
    """The platform tags of the file name (PEP 427: the last of its dash-separated fields,
    dot-compressed) and of the WHEEL metadata's ``Tag:`` lines, in order, without repeats."""
    tags = wheel.name.removesuffix(".whl").split("-")[-1].split(".")
    for name in archive.namelist():
        if re.fullmatch(r"[^/]+\.dist-info/WHEEL", name):
            for line in archive.read(name).decode().splitlines():
                if line.startswith("Tag:"):
                    tags.append(line.split(":", 1)[1].strip().split("-")[-1])
    return list(dict.fromkeys(tags))


def inspect(wheel: Path) -> WheelReport:
    try:
        archive = zipfile.ZipFile(wheel)
    except (OSError, zipfile.BadZipFile) as err:
        raise WheelCheckError(f"{wheel}: not a readable wheel ({err})") from err
    with archive:
        tags = platform_tags(wheel, archive)
        if not tags or tags == ["any"]:
            raise WheelCheckError(
                f"{wheel}: no platform tag (a pure wheel has nothing to check)"
            )
        report = WheelReport(str(wheel), tags, {tag: tag_glibc(tag) for tag in tags})
        for info in archive.infolist():
            data = archive.read(info) if not info.is_dir() else b""
            if not data.startswith(b"\x7fELF"):
                continue
            try:
                report.binaries[info.filename] = highest_glibc(
                    ELFFile(io.BytesIO(data))
                )
            except ELFError as err:
                raise WheelCheckError(
                    f"{wheel}: {info.filename} is a broken ELF file ({err})"
                )
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("wheels", nargs="+", type=Path, help="the wheels to check")
    parser.add_argument(
        "--max-glibc",
        type=parse_glibc,
        default=(2, 17),
        help="the newest glibc the wheels may need, MAJOR.MINOR (default 2.17: manylinux2014)",
    )
    args = parser.parse_args(argv)
    failed = False
    for wheel in args.wheels:
        try:
            report = inspect(wheel)
        except WheelCheckError as err:
            print(f"FAIL {err}")
            failed = True
            continue
        print(f"{wheel.name}: platform tags {', '.join(report.tags)}")
        for name, need in report.binaries.items():
            print(f"  {name}: highest glibc symbol {need[1] if need else 'none'}")
        problems = report.problems(args.max_glibc)
        for problem in problems:
            print(f"FAIL {wheel.name}: {problem}")
        if not problems:
            print(f"OK: runs on glibc >= {fmt(args.max_glibc)}")
        failed |= bool(problems)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
