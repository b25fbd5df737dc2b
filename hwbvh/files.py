"""Output files: checked before the work starts, written whole or not at all, JSON kept strict.

``check_outputs`` and ``check_output_dir`` fail at once, with an :class:`InputError` naming the
path as it was given, when an output could not be written or would replace an input; so a
long run never ends in an error about its output. ``write_files`` writes each file to a
temporary file beside it and renames it into place only when every file of the set is complete;
an exception (an interruption included) removes the temporary files, and a file that could not
be written (a full disk, a device error) is an :class:`OutputError` naming it. ``appending``
adds to a log of results (a benchmark's cells), creating or replacing it by a rename in the same
way. ``json_text`` is the one JSON encoder: strict JSON, with ``null`` for a number that is
infinite or undefined.
"""
import errno
import fcntl
import json
import math
import os
import signal
import tempfile
import threading
from contextlib import contextmanager

import numpy as np

from .config import DEFAULT_NAME_MAX
from .errors import InputError


# --------------------------------------------------------------------------------------
# strict JSON
# --------------------------------------------------------------------------------------
def jsonable(obj):
    """``obj`` with NumPy scalars and arrays turned into Python ones and every non-finite
    float (inf, -inf, nan) turned into ``None``; dict keys become strings."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return obj


def json_text(obj, indent=None):
    """Strict JSON text of ``obj`` (see :func:`jsonable`); never ``NaN`` or ``Infinity``."""
    return json.dumps(jsonable(obj), indent=indent, allow_nan=False)


# --------------------------------------------------------------------------------------
# checks before the work
# --------------------------------------------------------------------------------------
def _nearest_existing(path):
    d = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(d):
        parent = os.path.dirname(d)
        if parent == d:
            break
        d = parent
    return d


def _route_problem(directory):
    """Why the directory ``directory`` could not be reached or made as the system resolves its
    path, component by component (a ``..`` is taken after the component before it, not
    cancelled against it as ``abspath`` does), or None: a component that is a file, or a
    symbolic link to nothing, which no directory can be made in place of."""
    cur = os.sep if os.path.isabs(directory) else ""
    for part in directory.split(os.sep):
        if part in ("", os.curdir):
            continue
        cur = os.path.join(cur, part)
        if os.path.isdir(cur):
            continue
        if os.path.islink(cur):
            return f"{cur} is a symbolic link to {os.readlink(cur)}, which does not exist"
        if os.path.lexists(cur):
            return f"cannot create a directory under {cur}: it is a file"
        return None                     # missing from here on: made as the path says
    return None


def _directory_problem(d, wanted=None):
    """Why files cannot be created in the existing path ``d``, or None; ``wanted``: the
    missing directory below ``d`` that the output needs, which the message then names."""
    if not os.path.isdir(d):
        return f"cannot create a directory under {d}: it is a file"
    try:
        # an unnamed file where the output will go: the real permission check (ACLs, read-only
        # file systems), which os.access does not make for every user
        tempfile.TemporaryFile(dir=d).close()
    except OSError as e:
        reason = e.strerror or "not writable"
        if wanted and wanted != d:
            return f"cannot create the directory {wanted}: {d} takes no new files ({reason})"
        return f"cannot create files in {d} ({reason})"
    return None


def _long_name(path, d):
    """Why a name ``path`` needs made below its nearest existing directory ``d`` is longer
    than the file system takes, or None: found here, not when the finished work is renamed
    into place. The first such name is put to the file system itself (a lookup of it fails
    with ENAMETOOLONG, whatever the file system counts: bytes, or UTF-16 units on NTFS); a
    name below it, in a directory still to be made, is measured against what ``d``'s file
    system says it takes, in bytes (``DEFAULT_NAME_MAX`` where it says nothing)."""
    parts = [p for p in os.path.relpath(os.path.abspath(path), d).split(os.sep)
             if p not in ("", os.curdir, os.pardir)]
    if not parts:
        return None
    try:
        os.lstat(os.path.join(d, parts[0]))
    except OSError as e:
        if e.errno == errno.ENAMETOOLONG:
            return _too_long(parts[0], None)
    try:
        most = os.pathconf(d, "PC_NAME_MAX")
    except (OSError, ValueError):
        most = -1
    most = most if most > 0 else DEFAULT_NAME_MAX
    for part in parts[1:]:
        if len(os.fsencode(part)) > most:
            return _too_long(part, most)
    return None


def _too_long(name, most):
    shown = name if len(name) <= 40 else name[:20] + "..." + name[-12:]
    takes = "" if most is None else f"; its file system takes at most {most}"
    return f"the name {shown} is too long ({len(os.fsencode(name))} bytes){takes}"


def json_object_in(path, max_chars):
    """The JSON object the file ``path`` holds, or None: for a file that cannot be read, is
    not UTF-8 JSON, holds another JSON value, or runs past ``max_chars`` characters (a
    description of ours is far shorter, so a larger file is something else, and is not read
    whole)."""
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read(max_chars + 1)
        d = json.loads(text) if len(text) <= max_chars else None
    except (OSError, ValueError, RecursionError):
        return None
    return d if isinstance(d, dict) else None


def absent(path, problem):
    """What to say of an input ``path`` that does not exist: ``problem``, or, for a symbolic
    link, where it leads (a link to a missing file, or a loop of links, exists as a link)."""
    if os.path.islink(path):
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return (f"a symbolic link to {target}, which leads to no file (its target is missing, "
                f"or the links loop)")
    return problem


def directory_problem(path):
    """Why the file ``path`` could not be created where it lies (its directory, or the
    nearest existing one above), or None."""
    return _directory_problem(_nearest_existing(path), os.path.dirname(os.path.abspath(path)))


def file_identity(path):
    """``(st_dev, st_ino)`` of the existing file ``path`` (symlinks followed), else None: two
    spellings of one file that realpath cannot tie together (hard links, bind mounts)."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def with_companions(inputs):
    """``inputs`` and the files each one reads besides itself (a .gltf's buffer files)."""
    for src in map(os.fspath, inputs):
        yield src
        if isinstance(src, str) and src.lower().endswith(".gltf"):
            from .primitives import gltf_buffer_files
            yield from gltf_buffer_files(src)


def content_digest(path):
    """The first 16 hex digits of the SHA-256 of a file's bytes and those of the files it reads
    besides itself (``with_companions``: a .gltf's buffers), read a MiB at a time: what the
    resumable studies key a mesh's results by, so that a file given new contents under the
    same name is computed again."""
    import hashlib
    h = hashlib.sha256()
    for part in with_companions([os.fspath(path)]):
        with open(part, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:16]


class OutputPathError(InputError):
    """An output path that cannot be written, or would overwrite an input: the error names the
    output (a command reports the option that gave it, not an input option of the same
    value)."""


class NameTooLongError(OutputPathError):
    """An output path with a name longer than its file system takes."""


@contextmanager
def named_after(what, given, remedy):
    """Checks of an output that, unless a path was ``given``, is named after ``what`` (a
    scene's name): a name too long for its file system is then said to come from ``what``,
    with the ``remedy`` (the option that names the output)."""
    try:
        yield
    except NameTooLongError as e:
        if given is not None:
            raise
        raise NameTooLongError(e.source, f"{e.problem}: the name is made from {what}; "
                                         f"{remedy}") from None


def check_outputs(outputs, inputs=()):
    """Fail before any work unless every path in ``outputs`` can be written and none of them
    is one of ``inputs`` (or one another). Paths are reported as given. Raises
    OutputPathError.

    Linear in the number of paths (an animation names one output per frame): each path is
    resolved once and looked up in dicts, and the writability probe runs once per directory."""
    outputs = [os.fspath(p) for p in outputs if p is not None]
    input_by_path, input_by_id = {}, {}
    for src in with_companions(os.fspath(p) for p in inputs if p is not None):
        if not os.path.exists(src):
            continue
        input_by_path.setdefault(os.path.realpath(src), src)
        input_by_id.setdefault(file_identity(src), src)
    input_by_id.pop(None, None)
    seen_paths, seen_ids = set(), set()
    problems = {}                                # nearest existing directory -> problem or None
    for out in outputs:
        real = os.path.realpath(out)
        ident = file_identity(out)
        src = input_by_path.get(real) or (ident and input_by_id.get(ident))
        if src:
            same = "" if out == src else f" ({src})"
            raise OutputPathError(out, f"is an input of this run{same}; an output may not overwrite an input")
        if real in seen_paths or (ident and ident in seen_ids):
            raise OutputPathError(out, "is named twice as an output")
        seen_paths.add(real)
        if ident:
            seen_ids.add(ident)
        if os.path.isdir(out):
            raise OutputPathError(out, "is a directory; give a file path")
        if ident and not os.path.isfile(out):
            # an output is written whole beside it and renamed over it: a device or a pipe
            # would be replaced by a regular file, not written to
            raise OutputPathError(out, "is not a regular file (a device, pipe or socket); give a "
                                  "file path")
        if ident and not os.access(out, os.W_OK):
            raise OutputPathError(out, "exists and is read-only")
        d = _nearest_existing(out)
        key = (d, os.path.dirname(os.path.abspath(out)), os.path.dirname(out))
        if key not in problems:
            problems[key] = _route_problem(key[2]) or _directory_problem(d, key[1])
        if problems[key]:
            raise OutputPathError(out, problems[key])
        long = _long_name(out, d)
        if long:
            raise NameTooLongError(out, long)


def check_output_dir(directory, names=(), inputs=()):
    """Like :func:`check_outputs` for a directory that will hold the files ``names``; a problem
    with the directory itself names the directory."""
    directory = os.fspath(directory)
    if os.path.islink(directory) and not os.path.exists(directory):
        problem = f"is a symbolic link to {os.readlink(directory)}, which does not exist"
    elif os.path.exists(directory) and not os.path.isdir(directory):
        problem = "exists and is not a directory"
    elif os.path.exists(directory):
        problem = _directory_problem(directory)
    else:
        problem = _route_problem(os.path.dirname(directory)) or \
            _directory_problem(_nearest_existing(os.path.join(directory, "x")),
                               os.path.abspath(directory))
    if problem:
        raise OutputPathError(directory, problem)
    check_outputs([os.path.join(directory, n) for n in names], inputs)


# --------------------------------------------------------------------------------------
# atomic writes
# --------------------------------------------------------------------------------------
_HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def signals_held():
    """Hold SIGINT/SIGTERM for a short step (creating and recording a temporary file, the
    renames), so a set of files appears whole; a signal that arrives meanwhile is acted on
    right after, by the handler that was in place.

    The Python-level handlers are swapped, not the thread's signal mask: the kernel may deliver
    a process signal to any thread (image and thread-pool libraries start their own), and
    Python then runs the handler in the main thread at its next instruction, mask or not.
    Only the main thread runs Python signal handlers, so other threads need no holding. When
    both signals arrive in one hold, the first one's handler runs; if it raises, the program is
    already unwinding and the second is not replayed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    arrived = []
    previous = {}
    try:
        for sig in _HELD_SIGNALS:
            handler = signal.getsignal(sig)
            if handler is not None:                   # None: a handler set outside Python
                # recorded before the swap: a pending handler that raises as the swap returns
                # must not leave the recorder in place
                previous[sig] = handler
                signal.signal(sig, lambda signum, frame: arrived.append(signum))
        yield
    finally:
        interrupted = _restore_handlers(previous)
        if interrupted is not None:
            raise interrupted
        for sig in dict.fromkeys(arrived):
            handler = previous[sig]
            if callable(handler):
                handler(sig, None)
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), sig)        # the default action, now that it is back


def _restore_handlers(previous):
    """Put back every handler in ``previous``. A restored handler may run (and raise) as the
    next one is put back; the restoring goes on, and the first such exception is returned."""
    interrupted = None
    for sig, handler in previous.items():
        while True:
            try:
                signal.signal(sig, handler)
                break
            except BaseException as e:           # the pending signal is consumed; try again
                interrupted = interrupted or e
    return interrupted


class OutputError(OSError):
    """An output that could not be written although its checks passed (a full disk, a device
    error): ``filename`` is the path the caller asked for, ``strerror`` the reason."""


def _file_mode():
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def write_files(pairs):
    """Write several files so that either all appear or none.

    pairs : iterable of ``(path, data)``; ``data`` is bytes, str (written as UTF-8 text), or a
    callable ``write(tmp_path)`` that creates the file itself (e.g. an image library's writer).
    Each file goes to a temporary file in its directory, named with the same extension (for
    writers that choose the format by it); the renames happen only when every write succeeded.
    Missing directories are created; when the files do not all appear, those of them left
    empty are removed again.
    """
    tmps = []
    made = []                            # directories this call created, outermost first
    done = False
    try:
        for path, data in pairs:
            path = os.fsdecode(path)         # str, bytes or a path object: one str
            if os.path.isdir(path):
                raise IsADirectoryError(errno.EISDIR, "is a directory, not a file", path)
            try:
                # the directory as the system resolves the path (``abspath`` would cancel a
                # ``..`` against a directory that does not exist yet, which the rename needs)
                d = os.path.dirname(path if os.path.isabs(path) else
                                    os.path.join(os.getcwd(), path))
                for attempt in range(3):
                    make_directories(d, made)
                    try:
                        # held: a signal between creating and recording the temporary file
                        # would leave it behind; in the directory the path resolves to
                        # (mkstemp would cancel a ``..`` after a symbolic link)
                        with signals_held():
                            fd, tmp = tempfile.mkstemp(
                                prefix=".tmp-", suffix=os.path.splitext(path)[1],
                                dir=os.path.realpath(d))
                            tmps.append((tmp, path))
                        break
                    except FileNotFoundError:
                        # another writer that failed removed the directory it had made just
                        # as this one found it there: make it again
                        if attempt == 2:
                            raise
                if callable(data):
                    os.close(fd)
                    data(tmp)
                else:
                    with os.fdopen(fd, "w" if isinstance(data, str) else "wb") as f:
                        f.write(data)
                os.chmod(tmp, _file_mode())
            except OSError as e:
                if not e.errno:
                    raise
                # the error names the file the caller asked for, not its temporary file
                raise OutputError(e.errno, e.strerror, path) from None
        with signals_held():
            for tmp, path in tmps:
                try:
                    os.replace(tmp, path)
                except OSError as e:
                    raise OutputError(e.errno, e.strerror, path) from None
        done = True
    finally:
        with signals_held():             # a second signal does not cut the clean-up short
            for tmp, _ in tmps:          # (a renamed temporary file no longer exists)
                try:
                    os.unlink(tmp)
                except OSError:
                    pass
            for d in reversed(made if not done else ()):
                try:
                    os.rmdir(d)          # only if empty: another writer's files stay
                except OSError:
                    pass


@contextmanager
def appending(path, replace=False):
    """``path`` (a ``pathlib.Path``) opened to append to, in binary, its directory made;
    flushed to the disk at the end. A file that is not there yet, or with ``replace`` one whose
    content is to be replaced, is written to a temporary file beside it and renamed into place
    once what was written is on the disk, so that a failure leaves the old content (or no
    file), never an empty or partial one. A failed write (a full disk) is an
    :class:`OutputError` naming ``path``; an append it cut short in an existing file ends in a
    partial line, which a reader of such a log must pass over (``hwrt.study.Cells`` repairs
    it)."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if replace or not path.exists():
            with signals_held():            # a signal here would leave the file unrecorded
                fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=path.suffix,
                                           dir=path.parent)
            f = os.fdopen(fd, "wb")
        else:
            f = open(path, "ab")
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        if tmp is not None:
            os.chmod(tmp, _file_mode())
            with signals_held():
                os.replace(tmp, path)
                tmp = None
    except OSError as e:
        if not e.errno:
            raise
        raise OutputError(e.errno, e.strerror, str(path)) from None
    finally:
        if tmp is not None:
            with signals_held():
                try:
                    os.unlink(tmp)
                except OSError:
                    pass


@contextmanager
def held_directory(out_dir, command):
    """The directory ``out_dir``, made if missing, locked against other runs (an advisory lock
    on the directory itself, which the system lets go when the process ends however it ends;
    ``command``: the hwrt command a refusal names as the other run). A directory made here and
    still empty at the end is removed again, before the lock is let go (a run that takes it
    next then finds it gone, and makes it again). A file system that does not lock
    directories (NFS) leaves the run unlocked."""
    made, fd = [], None
    try:
        try:
            for attempt in range(2):
                make_directories(out_dir if os.path.isabs(out_dir) else
                                 os.path.join(os.getcwd(), out_dir), made)
                try:
                    fd = os.open(out_dir, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
                    break
                except FileNotFoundError:       # removed by a run that just ended: again
                    if attempt:
                        raise
        except OSError as e:
            raise InputError(out_dir, f"cannot be used as the output directory "
                                      f"({e.strerror or e})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(out_dir, f"another hwrt {command} is writing into it: let it end, "
                                      f"or choose another output directory") from None
        except OSError:
            pass                                # no locks here: the run goes on without one
        yield
    finally:
        for d in reversed(made):                # innermost first; one that holds files stays
            try:
                os.rmdir(d)
            except OSError:
                break
        if fd is not None:
            os.close(fd)


def make_directories(d, made):
    """Create the directory ``d`` and its missing parents, appending each one created to
    ``made`` (outermost first) as it is created, so that a signal between two of them leaves
    none unrecorded."""
    missing = []
    while not os.path.isdir(d):
        missing.append(d)
        parent = os.path.dirname(d)
        if parent == d:
            break
        d = parent
    for d in reversed(missing):
        with signals_held():
            try:
                os.mkdir(d)
            except FileExistsError:
                if not os.path.isdir(d):        # a file where a directory should be
                    raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR),
                                             d) from None
                continue
            made.append(d)


def made_as_written(make):
    """A ``write(tmp_path)`` for :func:`write_files` that calls ``make()`` (bytes, or a buffer
    such as an array) only as its file is written: a set of large files then holds one payload
    in memory at a time, not all of them."""
    def write(tmp):
        with open(tmp, "wb") as f:
            f.write(make())
    return write


def figure_png(fig, dpi=100):
    """A matplotlib figure as PNG bytes (for :func:`write_files`); closes the figure."""
    import io
    import matplotlib.pyplot as plt
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()
