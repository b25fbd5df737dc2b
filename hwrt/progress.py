"""Progress bars of the command line."""
import os
import sys

PROGRESS_ENV = "HWRT_PROGRESS"     # set: progress bars even where stderr is not a terminal


def progress_bar(total, desc, unit, initial=0):
    """A progress bar on stderr: shown on a terminal, or anywhere with HWRT_PROGRESS set."""
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr,
                disable=not sys.stderr.isatty() and not os.environ.get(PROGRESS_ENV))
