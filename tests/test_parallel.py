"""hwbvh.parallel.run_ranges: every range runs once, and nothing writes after it returns or
raises."""
import threading
import time

import numba
import numpy as np
import pytest

from hwbvh.parallel import run_ranges


def test_every_item_once_whatever_the_thread_count():
    before = numba.get_num_threads()
    try:
        for threads in (1, numba.config.NUMBA_NUM_THREADS):
            numba.set_num_threads(threads)
            hits = np.zeros(1000, np.int64)

            def kernel(lo, hi, out):
                out[lo:hi] += 1
            run_ranges(kernel, len(hits), hits)
            assert (hits == 1).all()
    finally:
        numba.set_num_threads(before)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_a_failing_range_stops_the_others_before_returning():
    written = np.zeros(64, np.int64)
    main = threading.get_ident()

    def kernel(lo, hi, out):
        if threading.get_ident() == main:
            raise RuntimeError("boom")
        time.sleep(0.01)
        out[lo:hi] = 1
    with pytest.raises(RuntimeError, match="boom"):
        run_ranges(kernel, len(written), written)
    after = written.copy()
    time.sleep(0.1)
    assert np.array_equal(written, after)       # no range wrote after run_ranges raised
