"""release_memory: freed heap memory goes back to the system (glibc), not only garbage."""

import numpy as np
import pytest

from wtml.memory import release_memory


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def test_release_returns_freed_heap():
    """Arrays of 96 kB (below glibc's mapping threshold: they live on the heap), every tenth
    kept so the freed ones are holes the heap cannot shrink past: ~170 MB that only
    ``malloc_trim`` hands back."""
    if not release_memory():
        pytest.skip("this C library has no malloc_trim (not glibc)")
    blocks = [np.ones(12_000) for _ in range(2000)]  # 2000 x 96 kB, touched
    kept = blocks[::10]
    del blocks
    before = _rss_mb()
    assert release_memory()
    after = _rss_mb()
    assert before - after > 100, (before, after)
    assert all(float(k[0]) == 1.0 for k in kept)


def test_fork_server_freezes_what_it_imported():
    """The fork server's last import moves every object it holds out of the collector's reach
    (so the lanes do not copy their pages); it is the last module the server preloads."""
    import subprocess
    import sys

    from wtml.pipeline import PRELOAD

    assert PRELOAD[-1] == "wtml.fork_server"
    code = ("import gc, numpy; assert gc.get_freeze_count() == 0; import wtml.fork_server; "
            "print(gc.get_freeze_count())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert int(out.stdout) > 10_000
