"""Issue 11, item 4: deform() releases the GIL, so Python threads call it concurrently. Results
must equal serial ones bit for bit, and nothing may hang (the run is in a fresh interpreter with
a timeout, so a deadlock fails the test instead of stalling pytest)."""

import threading
from pathlib import Path

from isolated import run_isolated

import matdeform as md

CONCURRENT = """
import sys
import threading
import numpy as np
import matdeform as md
from matdeform import shapes
sys.path.insert(0, {tests!r})
from conftest import rotation

md.set_num_threads(2)  # the task pool's parallel paths, also on a one-core machine
v, f = shapes.tube_with_faces(60000)  # large enough for the parallel blend and substitution
lo, hi = shapes.end_faces(v, f)
rng = np.random.default_rng(0)
shear = rng.uniform(0.2, 1.0, len(f))

def poses(k):
    out = []
    for i in range(k):
        T = np.tile(np.eye(4), (2, 1, 1))
        T[1, :3, :3] = (1 + 0.05 * i) * rotation(rng.normal(size=3), 0.3 * i)
        T[1, :3, 3] = rng.normal(size=3)
        out.append(T if i % 3 else T[:, :3, :3].copy())  # (k,3,3) too: its lazy factor
    return out

P = poses(9)
shared = md.MaterialDeformer(v, f, [lo, hi], shear=shear)
expect = [shared.deform(T) for T in P]
own = [None, None]
wrong = [0, 0]

def work(w):
    # Built here, both at once: the factorisations ran concurrently too (issue 11 follow-up:
    # the serial OpenBLAS under CHOLMOD is not safe for concurrent calls).
    own[w] = md.MaterialDeformer(v, f, [lo, hi], shear=shear)
    wrong[w] += not np.array_equal(own[w].weights, shared.weights)
    for rep in range(4):
        for i in range(len(P)):
            j = (i + 4 * w) % len(P)
            wrong[w] += not np.array_equal(own[w].deform(P[j]), expect[j])
            wrong[w] += not np.array_equal(shared.deform(P[j]), expect[j])
            wrong[w] += not np.array_equal(shared.face_transforms.shape, (len(f), 3, 3))

threads = [threading.Thread(target=work, args=(w,)) for w in range(2)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print("wrong", sum(wrong))
"""


def test_concurrent_deforms_match_serial_and_never_hang():
    code = CONCURRENT.replace("{tests!r}", repr(str(Path(__file__).parent)))
    rc, out, err = run_isolated(code, timeout=300)
    assert rc is not None, "concurrent deform() calls hung"
    assert rc == 0, f"crashed or failed (rc {rc}): {err[-2000:]}"
    assert out.split()[-2:] == ["wrong", "0"], out


def test_set_num_threads_reaches_threads_started_later():
    before = md.num_threads()
    try:
        for n in (1, 3):
            md.set_num_threads(n)
            seen = []
            t = threading.Thread(target=lambda out=seen: out.append(md.num_threads()))
            t.start()
            t.join()
            assert seen == [n]
    finally:
        md.set_num_threads(before)
