"""Progress bars of the command line."""
import sys

from .config import env_flag

PROGRESS_ENV = "HWRT_PROGRESS"     # on: progress bars even where stderr is not a terminal


def _hidden():
    return not sys.stderr.isatty() and not env_flag(PROGRESS_ENV)


def progress_bar(total, desc, unit, initial=0, show=True, **options):
    """A progress bar on stderr: shown on a terminal, or anywhere with HWRT_PROGRESS set (and
    never with ``show`` False). ``options`` go to tqdm."""
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr,
                disable=not show or _hidden(), **options)


def progress_over(items, desc, unit):
    """``items`` (a sequence or an iterator), with a progress bar as ``progress_bar`` shows."""
    from tqdm import tqdm
    return tqdm(items, desc=desc, unit=unit, file=sys.stderr, disable=_hidden())


def note_first_compile():
    """Where progress bars show, one line on stderr before a run that compiles the kernels
    into Numba's cache (the first on an install, or after its sources change): that run is
    otherwise silent while the compiler works (the README gives how long)."""
    if _hidden():
        return
    from raytracer.render import traversal_cached
    if not traversal_cached():
        print("hwrt: compiling the kernels into Numba's cache; later runs load them from it",
              file=sys.stderr, flush=True)
