"""``microhom.limits.release_free_memory``: glibc's ``malloc_trim`` hands the free heap pages
that small freed arrays leave behind back to the operating system (issue 26)."""
import gc
import sys

import numpy as np
import pytest

from microhom.limits import _malloc_trim, release_free_memory


def _rss_kib():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise AssertionError("no VmRSS")


@pytest.mark.skipif(not sys.platform.startswith("linux") or _malloc_trim() is None,
                    reason="glibc's malloc_trim: Linux with glibc only (returns False elsewhere, tested below)")
def test_freed_small_arrays_leave_the_resident_set():
    """200 MB of 16 KiB arrays (below the mmap threshold: on the heap), all freed but the last one
    (which keeps the heap's top, so the pages are not returned by themselves): at least 100 MB of
    resident memory goes back once released."""
    keep = [np.ones(2048) for _ in range(12800)]         # 12 800 x 16 KiB = 210 MB
    last = keep.pop()
    base = _rss_kib()
    del keep
    gc.collect()
    before = _rss_kib()
    assert release_free_memory() is True
    after = _rss_kib()
    assert base - before < 50_000                        # freed, but still resident
    assert before - after > 100_000, (base, before, after)
    assert last.sum() == 2048


def test_elsewhere_it_does_nothing(monkeypatch):
    import microhom.limits as lim
    monkeypatch.setattr(lim.sys, "platform", "darwin")
    assert lim._malloc_trim() is None and lim.release_free_memory() is False
