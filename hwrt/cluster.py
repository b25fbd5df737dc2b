"""Cells on Dask: one helper gives a client, another runs a list of cells through it.

By default the client talks to an embedded local cluster: one worker process per core, one
thread each, no dashboard, quiet logs, workers deaf to SIGINT on POSIX systems (a Ctrl-C is this
process's to act on: it closes the cluster). ``scheduler`` (or ``$HWRT_SCHEDULER``) names a running
Dask scheduler instead (``tcp://HOST:PORT``), whose workers must have hwrt installed and read the
inputs at the same paths. Each worker runs a warm-up once when it starts (Numba kernels loaded
from their cache, not once per cell). A cell lost with a killed worker is run again elsewhere
(Dask reschedules it); a cell that raises is retried. ``client=None`` runs the cells in this
process, one after the other: the reference a cluster's results equal bit for bit.
"""
import logging
import os
import signal
import sys
import threading
from contextlib import contextmanager

from distributed.diagnostics.plugin import WorkerPlugin

from hwbvh.errors import ParameterError, is_integer
from hwbvh.files import signals_held
from hwbvh.parallel import usable_cores

from .config import CONNECT_TIMEOUT_S, RETRIES, WORKER_WATCH_S
from .progress import progress_bar

SCHEDULER_ENV = "HWRT_SCHEDULER"
QUIET = ("distributed", "tornado", "asyncio", "bokeh")


CELL_THREADS_ENV = "HWRT_CELL_THREADS"     # Numba threads per cell on an embedded cluster's workers


def _cell(fn, *args):
    """Run a cell with the Numba thread count its worker's environment asks for
    (``CELL_THREADS_ENV``). Numba reads NUMBA_NUM_THREADS when first imported, which a worker
    does before its cluster's environment applies, and its thread count is a setting of the
    calling thread: so it is set here, in the thread that runs the cell."""
    want = os.environ.get(CELL_THREADS_ENV)
    if want:
        import numba
        numba.set_num_threads(max(1, min(int(want), numba.config.NUMBA_NUM_THREADS)))
    return fn(*args)


class WarmUp(WorkerPlugin):
    """Worker plugin: run ``fn`` once in each worker process when it starts (and in a
    replacement after a kill). ``fn`` must be importable on the workers (a module-level
    function of hwrt)."""

    name = "hwrt-warm-up"

    def __init__(self, fn):
        self.fn = fn

    def setup(self, worker):
        self.fn()


def _quiet():
    for name in QUIET:
        logging.getLogger(name).setLevel(logging.CRITICAL)


NETWORK_SCHEMES = ("tcp", "tls", "ws", "wss")     # Dask's, besides inproc:// (one process's)


def _address_problem(address):
    """What makes ``address`` no address to connect to (a scheme that is not a network's, no
    port, a port out of range), or None: said at once, where a connection attempt would wait
    out its timeout first."""
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        if scheme == "inproc":          # a scheduler of this process (the Python API's use)
            return None
        if scheme not in NETWORK_SCHEMES:
            return (f"its scheme {scheme!r} is not one a scheduler on the network listens on "
                    f"({', '.join(NETWORK_SCHEMES)})")
        _, colon, text = location.rpartition(":")
        if colon and text and not text.isdigit():           # int() would say it its own way
            return f"port {text!r} is not a number"
        port = parse_host_port(location)[1]
        if not 1 <= port <= 65535:
            return f"port {port} is not in 1..65535"
    except (ValueError, TypeError) as e:
        return (str(e).splitlines() or [""])[0] or type(e).__name__
    return None


def _probe(address):
    """Why ``address`` is not a Dask scheduler answering within ``CONNECT_TIMEOUT_S``, or None.
    Asked before a Client exists, so that a bad address (nothing listening, no route, a server
    that is not Dask) fails quickly and leaves nothing behind to close."""
    import asyncio
    from distributed.comm import connect

    async def ask():
        comm = await connect(address, timeout=CONNECT_TIMEOUT_S)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    try:
        reply = asyncio.run(asyncio.wait_for(ask(), 2 * CONNECT_TIMEOUT_S))
    except (OSError, TimeoutError, ValueError) as e:     # refused, timed out, unroutable, bad address
        if address.startswith("inproc://"):
            return "an inproc address names a scheduler of this process, and none has it"
        return (str(e).splitlines() or [""])[0] or type(e).__name__
    except Exception as e:                               # a server that does not speak Dask
        return f"the server there does not speak Dask's protocol: {type(e).__name__}"
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        return "the server there is not a Dask scheduler"
    return None


@contextmanager
def _sigint_blocked():
    """SIGINT blocked in this thread while the embedded cluster starts, and so in the threads
    it starts meanwhile (its event loop, and the threads that loop starts to spawn worker
    processes, now or to replace one later) and in those processes: a signal mask is inherited
    by threads and across fork and exec. Ctrl-C at a terminal signals every process of the
    foreground group; this way only this process acts on it (its main thread unblocks SIGINT
    again), and it closes the cluster, instead of each worker dying with a traceback."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    # multiprocessing starts its resource tracker the first time a worker's queue is made,
    # and unblocks both signals in the thread that starts it: started here first, it is not
    # started again in the event loop's thread, whose mask stays as this one leaves it
    from multiprocessing import resource_tracker
    resource_tracker.ensure_running()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def address_source(scheduler):
    """What an error about the scheduler blames: the ``scheduler`` argument when given, else
    ``$HWRT_SCHEDULER``, where ``dask_client`` then takes the address from."""
    return "scheduler" if scheduler else f"${SCHEDULER_ENV}"


def _require_workers(client, named):
    """Wait up to ``CONNECT_TIMEOUT_S`` for a worker on ``client``'s scheduler (one started
    beside it may still be joining), then raise ParameterError naming ``named``: cells sent to
    a scheduler without workers would wait for ever."""
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except TimeoutError:
        raise ParameterError(named, f"the Dask scheduler at {client.scheduler.address} has no "
                                    f"workers (none joined within {CONNECT_TIMEOUT_S} s)") from None


@contextmanager
def dask_client(scheduler=None, *, workers=None, threads_per_cell=1, warm_up=None):
    """A ``distributed.Client``: on ``scheduler`` (else ``$HWRT_SCHEDULER``), else on an
    embedded local cluster of ``workers`` processes (default and most: one per core the process
    may use, ``hwbvh.parallel.usable_cores``) whose Numba kernels get ``threads_per_cell``
    threads each. ``warm_up`` runs once per worker. Raises ParameterError naming "workers" for
    a local cluster of another size; naming "scheduler", or "$HWRT_SCHEDULER" when the address
    came from there, for an address that is none, a scheduler that does not answer within
    ``CONNECT_TIMEOUT_S``, and one that no worker joins within that time."""
    import dask
    from distributed import Client, LocalCluster

    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    cores = usable_cores()
    if not address and workers is not None and \
            not (is_integer(workers) and 1 <= workers <= cores):
        raise ParameterError("workers", f"must be a whole number from 1 to {cores}, the cores "
                                        f"this process may use (a cell keeps a core busy: more "
                                        f"worker processes would only share them), got {workers!r}")
    _quiet()
    named = address_source(scheduler)
    cluster = client = None
    # settings for this cluster only: restored when it closes, so the caller's process keeps
    # its own Dask configuration. The short connect timeout is for a scheduler elsewhere (an
    # address that does not answer fails fast); a local cluster's workers, started on a busy
    # machine, keep Dask's own
    settings = {"distributed.scheduler.allowed-failures": 8, "distributed.worker.daemon": False}
    if address:
        settings["distributed.comm.timeouts.connect"] = f"{CONNECT_TIMEOUT_S}s"
    with dask.config.set(settings):
        try:
            if address:
                malformed = _address_problem(address)
                if malformed:
                    raise ParameterError(named, f"{address!r} is not a scheduler address "
                                                f"({malformed}; e.g. tcp://HOST:8786)")
                problem = _probe(address)
                if problem:
                    raise ParameterError(named, f"no Dask scheduler answers at {address!r} "
                                                f"within {CONNECT_TIMEOUT_S} s ({problem})")
                client = Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
                _require_workers(client, named)
            else:
                n = workers or cores
                threads = str(max(1, int(threads_per_cell)))
                # a Ctrl-C while the cluster starts is held (the Python handler: the mask
                # does not hold a signal the kernel hands another thread) and acted on once
                # the cluster is made, which is then closed below; the scheduler's HTTP port
                # is left to the system: 8787 may be another cluster's
                with signals_held(), _sigint_blocked():
                    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.CRITICAL,
                                           scheduler_kwargs={"dashboard_address": ":0"},
                                           env={CELL_THREADS_ENV: threads,
                                                "OMP_NUM_THREADS": threads})
                client = Client(cluster, set_as_default=False)
            if warm_up is not None:
                client.register_plugin(WarmUp(warm_up))
            yield client
        finally:
            _quiet()
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()


def describe(client):
    """Where ``client`` runs cells, in words."""
    n = len(client.scheduler_info().get("workers", {}))
    if client.cluster is not None:
        return f"a local Dask cluster of {n} worker process{'' if n == 1 else 'es'}"
    return f"the Dask scheduler at {client.scheduler.address} ({n} worker{'' if n == 1 else 's'})"


def timing_host(client, named="scheduler"):
    """The host (as in the workers' addresses) where ``client``'s timed cells run: the first
    in address order, so that every timing of a run comes from one machine. A scheduler
    without workers raises ParameterError naming ``named`` (``address_source``)."""
    from distributed.comm import get_address_host

    hosts = sorted({get_address_host(w) for w in client.scheduler_info().get("workers", {})})
    if not hosts:
        raise ParameterError(named, f"the Dask scheduler at {client.scheduler.address} "
                                    f"has no workers")
    return hosts[0]


@contextmanager
def workers_watched(client, every=WORKER_WATCH_S, say=None):
    """While the block runs, check every ``every`` seconds that ``client``'s scheduler has a
    worker; when it has none (every worker lost), say so once on stderr (``say``: a callable
    taking the line): Dask then waits, silently, until a worker joins, and the run goes on."""
    say = say or (lambda line: print(line, file=sys.stderr, flush=True))
    done = threading.Event()

    def watch():
        told = False
        while not done.wait(every):
            try:
                none = not client.scheduler_info().get("workers")
            except Exception:           # a scheduler going away is the run's own error
                return
            if none and not told:
                say(f"hwrt: the Dask scheduler at {client.scheduler.address} has no workers "
                    f"left; waiting for one to join (the run goes on when one does)")
            told = none
    t = threading.Thread(target=watch, name="hwrt-worker-watch", daemon=True)
    t.start()
    try:
        yield
    finally:
        done.set()
        t.join()


def run_cells(cells, on_result, client=None, desc="cells", weight=None, progress=True, host=None):
    """Run ``cells`` (a list of ``(key, fn, args)``) and call ``on_result(key, result)`` in this
    process as each finishes, with a progress bar over ``weight(key)`` units (default 1 each)
    on stderr. ``client=None`` runs them here, in order.

    ``host`` (see :func:`timing_host`) runs the cells one at a time, in order, on that host's
    workers: a timed cell then shares the machine with no other cell of the run, whatever the
    cluster's shape. Should every worker there be lost, the cell runs on another host rather
    than wait."""
    weight = weight or (lambda key: 1)
    total = sum(weight(k) for k, _, _ in cells)
    bar = progress_bar(total, desc, "cell", show=progress, smoothing=0.05)
    try:
        if client is None:
            for key, fn, args in cells:
                on_result(key, fn(*args))
                bar.update(weight(key))
            return
        with workers_watched(client):
            _run_on(client, cells, on_result, weight, bar, host)
    finally:
        bar.close()


def _run_on(client, cells, on_result, weight, bar, host):
    """``run_cells`` on a cluster."""
    if host is not None:
        for key, fn, args in cells:
            fut = client.submit(_cell, fn, *args, key=key, pure=False, retries=RETRIES,
                                workers=[host], allow_other_workers=True)
            on_result(key, fut.result())
            fut.release()
            bar.update(weight(key))
        return
    from distributed import as_completed
    futures = {client.submit(_cell, fn, *args, key=key, pure=False, retries=RETRIES): key
               for key, fn, args in cells}
    for fut in as_completed(futures, loop=client.loop):
        key = futures[fut]
        on_result(key, fut.result())
        fut.release()
        bar.update(weight(key))
