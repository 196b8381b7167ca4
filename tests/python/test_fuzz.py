"""Seeded fuzz of the public API (tests/python/fuzz.py) in subprocesses, so that a crash or a
hang is counted against the case that caused it instead of ending pytest.

MD_FUZZ_N cases (default 300) of seed MD_FUZZ_SEED (default 0). A longer run:
    MD_FUZZ_N=5000 .venv/bin/python -m pytest -q tests/python/test_fuzz.py
or, with a table per function:
    MD_FUZZ_N=5000 .venv/bin/python tests/python/test_fuzz.py
"""

from __future__ import annotations

import collections
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

FUZZ = Path(__file__).with_name("fuzz.py")
FAILURES = ("error", "nan", "permutation", "crash", "hang")


def run_fuzz(seed: int, n: int) -> list[dict]:
    """One result per case; a worker that dies or hangs is restarted after the case it was in."""
    results: list[dict] = []
    i = 0
    while i < n:
        count = n - i
        try:
            p = subprocess.run(
                [sys.executable, str(FUZZ), str(seed), str(i), str(count)],
                capture_output=True,
                text=True,
                timeout=120 + 0.5 * count,
                cwd=FUZZ.parent,
            )
            out, died = p.stdout, None if p.returncode == 0 else f"crash (exit {p.returncode})"
        except subprocess.TimeoutExpired as e:
            out = e.stdout.decode() if isinstance(e.stdout, bytes) else (e.stdout or "")
            died = "hang"
        started = function = None
        for line in out.splitlines():
            if line.startswith("start "):
                started, function = int(line.split()[1]), line.split()[2]
            elif line.startswith("{"):
                results.append(json.loads(line))
                started = None
        if died is None:
            break
        if started is None:  # died outside a case (e.g. at import): nothing more to learn
            results.append({"i": i, "function": "?", "status": "crash", "detail": died})
            break
        status = "hang" if died == "hang" else "crash"
        results.append({"i": started, "function": function, "status": status, "detail": died})
        i = started + 1
    return results


def summary(results: list[dict]) -> str:
    per = collections.defaultdict(collections.Counter)
    for r in results:
        per[r["function"]][r["status"]] += 1
    total = collections.Counter(r["status"] for r in results)
    lines = [f"{len(results)} cases: " + ", ".join(f"{k} {v}" for k, v in sorted(total.items()))]
    for fn in sorted(per):
        lines.append(f"  {fn}: " + ", ".join(f"{k} {v}" for k, v in sorted(per[fn].items())))
    return "\n".join(lines)


def test_fuzz_public_api():
    seed = int(os.environ.get("MD_FUZZ_SEED", "0"))
    n = int(os.environ.get("MD_FUZZ_N", "300"))
    results = run_fuzz(seed, n)
    print(summary(results))
    assert len(results) == n
    bad = [r for r in results if r["status"] in FAILURES]
    assert not bad, "\n".join(json.dumps(r) for r in bad[:20])
    # The generator must exercise both outcomes of most functions, or it tests little.
    statuses = collections.Counter(r["status"] for r in results)
    assert statuses["ok"] > n / 2 and statuses["rejected"] > n / 10


# Cases longer runs found (seed, case, what it caught), rerun on every test run: each failed
# before its fix. They depend on the generator: a change to fuzz.py that moves them is a reason
# to find them again with the same long run.
KNOWN = [
    (13, 2253, "pose space: a free rotational pair joined two gauges (92 units apart)"),
    (13, 3263, "pose space: a coarse handle face picked by round-off among tied weights"),
    (36, 2699, "edge: relabelling round-off at stretch / bend 2.8e-7, past the measured 1e-6"),
]


@pytest.mark.parametrize("seed,case,what", KNOWN)
def test_known_findings_stay_fixed(seed, case, what):
    result = subprocess.run(
        [sys.executable, str(FUZZ), str(seed), str(case), "1"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=FUZZ.parent,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    record = json.loads(result.stdout.splitlines()[-1])
    assert record["status"] in ("ok", "rejected"), (what, record)


def test_a_crash_is_counted_and_the_run_goes_on(monkeypatch):
    """The harness itself: a worker killed by a signal in case 3 costs that case only."""
    monkeypatch.setenv("MD_FUZZ_CRASH_AT", "3")
    results = run_fuzz(0, 6)
    assert [r["i"] for r in results] == list(range(6))
    assert [r["status"] == "crash" for r in results] == [False, False, False, True, False, False]


if __name__ == "__main__":
    seed, n = int(os.environ.get("MD_FUZZ_SEED", "0")), int(os.environ.get("MD_FUZZ_N", "300"))
    print(summary(run_fuzz(seed, n)))
