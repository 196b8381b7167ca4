"""Can this Blender load the native core that the zip carries? Answered from the tags of the
bundled ``matdeform`` wheel (legacy zip: ``_vendor/matdeform-*.dist-info/WHEEL``; extension:
``wheels/matdeform-*.whl``), before anything imports it, so that an unsupported platform gets
one clear sentence instead of a failed import. No bpy here: testable anywhere.
"""

from __future__ import annotations

import glob
import os
import platform
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

# manylinux aliases of PEP 513/571/599 -> the glibc they stand for (PEP 600)
_MANYLINUX_ALIAS = {"manylinux1": (2, 5), "manylinux2010": (2, 12), "manylinux2014": (2, 17)}
_ARCH = {"x86_64": "x86-64", "amd64": "x86-64", "aarch64": "arm64", "arm64": "arm64"}


def wheel_tags(addon_dir: str = HERE) -> list[str]:
    """The tags of every bundled core as ``python-abi-platform`` strings, e.g.
    ``["cp311-cp311-manylinux_2_35_x86_64", "cp313-cp313-manylinux_2_35_x86_64"]``; [] when no
    wheel is bundled (a source tree)."""
    tags: list[str] = []
    for info in sorted(glob.glob(os.path.join(addon_dir, "_vendor", "*.dist-info", "WHEEL"))):
        with open(info, encoding="utf-8") as f:
            tags += [line.split(":", 1)[1].strip() for line in f if line.startswith("Tag:")]
    for whl in sorted(glob.glob(os.path.join(addon_dir, "wheels", "matdeform-*.whl"))):
        py, abi, plat = os.path.basename(whl)[: -len(".whl")].split("-")[-3:]
        # compressed tag sets: "manylinux_2_17_x86_64.manylinux2014_x86_64" is two tags
        pys, abis, plats = py.split("."), abi.split("."), plat.split(".")
        tags += [f"{p}-{a}-{q}" for p in pys for a in abis for q in plats]
    return list(dict.fromkeys(tags))


def current() -> dict:
    """This interpreter's platform, in the terms the tags use."""
    glibc = None
    try:
        name, _, ver = (os.confstr("CS_GNU_LIBC_VERSION") or "").partition(" ")
        if name == "glibc":
            glibc = tuple(int(x) for x in ver.split(".")[:2])
    except (AttributeError, ValueError, OSError):
        pass  # not glibc (Windows, macOS, musl)
    return {
        "python": sys.version_info[:2],
        "implementation": sys.implementation.name,
        "os": sys.platform,
        "machine": platform.machine().lower(),
        "glibc": glibc,
    }


def _platform_ok(plat: str, here: dict) -> bool:
    if plat == "any":
        return True
    arch = _ARCH.get(here["machine"], here["machine"])
    m = re.fullmatch(r"(manylinux_(\d+)_(\d+)|manylinux1|manylinux2010|manylinux2014)_(\w+)", plat)
    if m:
        need = (int(m[2]), int(m[3])) if m[2] else _MANYLINUX_ALIAS[m[1]]
        return (
            here["os"].startswith("linux")
            and _ARCH.get(m[4], m[4]) == arch
            and here["glibc"] is not None
            and here["glibc"] >= need
        )
    m = re.fullmatch(r"linux_(\w+)", plat)
    if m:
        return here["os"].startswith("linux") and _ARCH.get(m[1], m[1]) == arch
    if plat == "win_amd64":
        return here["os"] == "win32" and arch == "x86-64"
    if plat == "win_arm64":
        return here["os"] == "win32" and arch == "arm64"
    m = re.fullmatch(r"macosx_\d+_\d+_(\w+)", plat)
    if m:
        archs = {"x86-64", "arm64"} if m[1] == "universal2" else {_ARCH.get(m[1], m[1])}
        return here["os"] == "darwin" and arch in archs
    return False  # musllinux and anything else: not built here


def _python_ok(py: str, abi: str, here: dict) -> bool:
    if py in ("py3", f"py{here['python'][0]}"):
        return True
    m = re.fullmatch(r"cp(\d)(\d+)", py)
    if not m or here["implementation"] != "cpython":
        return False
    built = (int(m[1]), int(m[2]))
    return built == here["python"] or (abi == "abi3" and here["python"] >= built)


def describe_tag(tag: str) -> str:
    """``cp311-cp311-manylinux_2_35_x86_64`` -> ``CPython 3.11 on Linux x86-64 (glibc 2.35 or
    newer)``."""
    py, _, plat = tag.split("-")
    m = re.fullmatch(r"cp(\d)(\d+)", py)
    who = f"CPython {m[1]}.{m[2]}" if m else py
    m = re.fullmatch(r"manylinux_(\d+)_(\d+)_(\w+)", plat)
    if m:
        return f"{who} on Linux {_ARCH.get(m[3], m[3])} (glibc {m[1]}.{m[2]} or newer)"
    m = re.fullmatch(r"linux_(\w+)", plat)
    if m:
        return f"{who} on Linux {_ARCH.get(m[1], m[1])}"
    m = re.fullmatch(r"win_(\w+)", plat)
    if m:
        return f"{who} on Windows {_ARCH.get(m[1], m[1])}"
    m = re.fullmatch(r"macosx_(\d+)_(\d+)_(\w+)", plat)
    if m:
        return f"{who} on macOS {_ARCH.get(m[3], m[3])} ({m[1]}.{m[2]} or newer)"
    return f"{who} on {plat}"


def describe_current(here: dict) -> str:
    os_name = {"win32": "Windows", "darwin": "macOS"}.get(here["os"], here["os"].capitalize())
    glibc = f", glibc {here['glibc'][0]}.{here['glibc'][1]}" if here["glibc"] else ""
    arch = _ARCH.get(here["machine"], here["machine"])
    return f"Python {here['python'][0]}.{here['python'][1]} on {os_name} {arch}{glibc}"


def problem(tags: list[str], here: dict) -> str | None:
    """None if some tag fits ``here`` (or nothing is bundled to check); else why it cannot run."""
    for tag in tags:
        py, abi, plat = tag.split("-")
        if _python_ok(py, abi, here) and _platform_ok(plat, here):
            return None
    if not tags:
        return None
    built = []  # one phrase per Python and platform, in the order bundled
    for tag in tags:
        phrase = describe_tag(tag)
        if phrase not in built:
            built.append(phrase)
    return (
        f"its native core is built for {_join(built)}, and this Blender has "
        f"{describe_current(here)}. Install a build of Material Deform made for this platform "
        "(docs/addon.md, 'Platforms')."
    )


def _join(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def problem_here(addon_dir: str = HERE) -> str | None:
    return problem(wheel_tags(addon_dir), current())
