"""Put every wheel's native core into each of the others: ``python share_cores.py WHEEL...``.

Each wheel keeps its own tags, and Python imports only the ``_core.cpython-3XX-*.so`` of its
own version, so a wheel then works whichever of them Blender installs. Blender 4.2.0 installs
one wheel per package whatever its Python tag (the cp313 one into Python 3.11); later versions
pick by tag."""

import base64
import hashlib
import re
import sys
import zipfile
from pathlib import Path

CORE = re.compile(r"matdeform/_core\.[^/]+\.(so|pyd)")


def digest(data: bytes) -> str:
    return base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()


wheels = [Path(p) for p in sys.argv[1:]]
cores = {}
for w in wheels:
    with zipfile.ZipFile(w) as z:
        cores.update({n: z.read(n) for n in z.namelist() if CORE.fullmatch(n)})
for w in wheels:
    with zipfile.ZipFile(w) as z:
        items = [(i, z.read(i)) for i in z.infolist()]
    names = {i.filename for i, _ in items}
    extra = {n: d for n, d in cores.items() if n not in names}
    if not extra:
        continue
    tmp = w.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as out:
        for item, data in items:
            if item.filename.endswith(".dist-info/RECORD"):
                lines = "".join(f"{n},sha256={digest(d)},{len(d)}\n" for n, d in extra.items())
                data += lines.encode()
            out.writestr(item, data)
        for name, data in extra.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = 0o755 << 16
            out.writestr(info, data, zipfile.ZIP_DEFLATED)
    tmp.replace(w)
    print(f"{w.name}: + {', '.join(Path(n).name for n in extra)}")
