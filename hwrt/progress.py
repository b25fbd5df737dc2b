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
