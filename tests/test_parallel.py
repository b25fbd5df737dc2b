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


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_a_pool_thread_not_yet_running_is_not_waited_for():
    """On a busy machine a pool thread may not be scheduled for a while: the calling thread
    does every range meanwhile and returns without waiting for it."""
    from hwbvh.parallel import _executor

    release = threading.Event()
    freed = threading.Semaphore(0)

    def hold_up():
        release.wait(5.0)
        freed.release()
    for _ in range(numba.config.NUMBA_NUM_THREADS - 1):            # the pool is held up
        _executor().submit(hold_up)
    try:
        hits = np.zeros(1000, np.int64)

        def kernel(lo, hi, out):
            out[lo:hi] += 1
        t = time.perf_counter()
        run_ranges(kernel, len(hits), hits)
        assert time.perf_counter() - t < 2.0 and (hits == 1).all()
    finally:
        release.set()
        for _ in range(numba.config.NUMBA_NUM_THREADS - 1):
            freed.acquire()
    time.sleep(0.05)                            # the late pool threads found nothing to do
    assert (hits == 1).all()


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_ranges_asked_for_inside_a_range_run_on_its_thread():
    seen = []

    def inner(lo, hi, outer_thread):
        seen.append((threading.get_ident() == outer_thread, lo, hi))

    def outer(lo, hi):
        for _ in range(lo, hi):
            run_ranges(inner, 1000, threading.get_ident())
    run_ranges(outer, 8, parts=8)
    assert len(seen) == 8 and all(same and (lo, hi) == (0, 1000) for same, lo, hi in seen)
    seen.clear()
    run_ranges(inner, 1000, None)                   # outside a range: split across threads
    assert len(seen) > 1


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_an_interrupt_while_waiting_lets_running_ranges_end_first():
    """Ctrl-C while the calling thread waits for a pool thread's range: the range ends before
    the interrupt propagates, so nothing writes into the caller's arrays afterwards. The steps
    are ordered by events, not by sleeps, so a slow machine cannot reorder them."""
    import os
    import signal
    main = threading.get_ident()
    written = np.zeros(2, np.int64)
    pool_started, sent = threading.Event(), threading.Event()
    pool_range = []

    def kernel(lo, hi, out):
        if threading.get_ident() == main:
            assert pool_started.wait(30)            # the other range runs on the pool thread
        else:
            pool_range.append(lo)
            pool_started.set()
            assert sent.wait(30)                    # still running when the interrupt comes
            time.sleep(0.1)
        out[lo:hi] = 1

    def interrupt():
        pool_started.wait(30)
        os.kill(os.getpid(), signal.SIGINT)
        sent.set()

    sender = threading.Thread(target=interrupt, daemon=True)
    sender.start()
    with pytest.raises(KeyboardInterrupt):
        run_ranges(kernel, 2, written, parts=2)
    # the pool thread's range had ended (this thread's own range may have been the one
    # interrupted, so it may not have written)
    assert written[pool_range[0]] == 1
    after = written.copy()
    sender.join(30)
    time.sleep(0.2)
    assert np.array_equal(written, after)


def test_a_shared_counter_hands_out_every_item_once():
    """``fetch_add`` from every thread of a parallel loop: each item is taken exactly once."""
    from numba import njit, prange
    from hwbvh.parallel import fetch_add

    @njit(parallel=True)
    def take_all(n, threads, counter, taken_by):
        for k in prange(threads):
            while True:
                t = fetch_add(counter, 0, 1)
                if t >= n:
                    break
                taken_by[t] += 1

    threads = max(2, numba.get_num_threads())
    taken_by = np.zeros(100_000, np.int64)
    counter = np.zeros(1, np.int64)
    take_all(len(taken_by), threads, counter, taken_by)
    assert (taken_by == 1).all()
    assert counter[0] == len(taken_by) + threads        # and one take past the end per thread


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_pool_threads_let_go_of_what_a_finished_call_worked_on():
    """A pool thread drops its job when the job ends, not when the next one comes: a job's
    closure holds the call's arguments (a render's frame, its tracer and film)."""
    import gc
    import weakref

    class Frame:
        pass

    frame = Frame()
    gone = weakref.ref(frame)

    def kernel(lo, hi, frame):
        time.sleep(0.01)

    # each pool thread takes the job (run a range or find none left), then waits for the next
    run_ranges(kernel, 8, frame, parts=8)
    del frame
    deadline = time.monotonic() + 5
    while gone() is not None and time.monotonic() < deadline:
        gc.collect()
        time.sleep(0.01)
    assert gone() is None
