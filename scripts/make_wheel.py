"""Pack the matdeform package and a native core built for another CPython (build_core_wheel.sh)
into a wheel, the same files a scikit-build-core build of that Python would hold:
    python make_wheel.py CORE_SO TAG OUTDIR     e.g. TAG cp313-cp313-linux_x86_64
Prints the wheel's path."""

import base64
import hashlib
import re
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
core, tag, outdir = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
pyproject = (ROOT / "pyproject.toml").read_text()
version = re.search(r'^version = "([^"]+)"', pyproject, re.M)[1]
requires_python = re.search(r'^requires-python = "([^"]+)"', pyproject, re.M)[1]
deps = re.findall(r'"([^"]+)"', re.search(r"^dependencies = \[(.*)\]", pyproject, re.M)[1])
summary = re.search(r'^description = "([^"]+)"', pyproject, re.M)[1]

info = f"matdeform-{version}.dist-info"
package = sorted((ROOT / "src" / "matdeform").glob("*.py"))
files = {f"matdeform/{p.name}": p.read_bytes() for p in package}
files[f"matdeform/{core.name}"] = core.read_bytes()
files[f"{info}/METADATA"] = (
    f"Metadata-Version: 2.1\nName: matdeform\nVersion: {version}\nSummary: {summary}\n"
    f"License: GPL-3.0-or-later\nRequires-Python: {requires_python}\n"
    + "".join(f"Requires-Dist: {d}\n" for d in deps)
).encode()
files[f"{info}/WHEEL"] = (
    f"Wheel-Version: 1.0\nGenerator: matdeform make_wheel.py\nRoot-Is-Purelib: false\nTag: {tag}\n"
).encode()


def digest(data: bytes) -> str:
    return base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


record = "".join(f"{n},sha256={digest(d)},{len(d)}\n" for n, d in files.items())
files[f"{info}/RECORD"] = (record + f"{info}/RECORD,,\n").encode()
outdir.mkdir(parents=True, exist_ok=True)
out = outdir / f"matdeform-{version}-{tag}.whl"
with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
    for name, data in files.items():
        item = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
        item.external_attr = (0o755 if name.endswith(core.suffix) else 0o644) << 16
        item.compress_type = zipfile.ZIP_DEFLATED
        z.writestr(item, data)
print(out)
