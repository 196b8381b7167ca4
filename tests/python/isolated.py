"""Run Python code in a fresh interpreter, so that a segfault or a hang fails a test instead of
ending or stalling pytest."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def run_isolated(code: str, timeout: float = 60.0, env: dict | None = None):
    """(returncode, stdout, stderr) of `python -c code`; returncode < 0 is a signal (a crash),
    None a timeout (a hang)."""
    try:
        p = subprocess.run(
            [sys.executable, "-c", textwrap.dedent(code)],
            capture_output=True,
            text=True,
            timeout=timeout,
            env=env,
        )
    except subprocess.TimeoutExpired as e:
        return None, e.stdout or "", e.stderr or ""
    return p.returncode, p.stdout, p.stderr


def outcome(call: str, setup: str = "") -> str:
    """Evaluates `call` after `setup` in a fresh interpreter (numpy as np, matdeform as md and
    matdeform._core as _core imported). Returns "ok", "ValueError: <message>", another exception
    name with its message, "signal <n>" for a crash or "timeout"."""
    code = f"""
import numpy as np
import matdeform as md
from matdeform import _core
{textwrap.dedent(setup)}
try:
    {call}
except Exception as e:
    print(type(e).__name__ + ": " + str(e))
else:
    print("ok")
"""
    rc, out, err = run_isolated(code)
    if rc is None:
        return "timeout"
    if rc < 0:
        return f"signal {-rc}"
    if rc != 0:
        return f"exit {rc}: {err.strip().splitlines()[-1] if err.strip() else ''}"
    return out.strip().splitlines()[-1]
