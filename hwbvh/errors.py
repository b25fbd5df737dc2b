"""Errors that name the input and the problem; the CLI turns them into exit status 2. With
the two checks every message uses: what counts as an integer, and a value shown cut short."""
import numpy as np


class InputError(ValueError):
    """Bad input: a missing or malformed file, bad coordinates, an out-of-range parameter.

    The message is one line and names the file (or argument) and the problem.
    """

    def __init__(self, source, problem):
        self.source = str(source)
        self.problem = str(problem)
        super().__init__(f"{self.source}: {self.problem}")


class ParameterError(InputError):
    """A function argument out of range. ``parameter`` is the argument's name as the function
    spells it (``leaf_size``); a command line reports its own option for it (``--leaf-size``).
    ``remedy``: what a caller of the library can do about it, written after the finding
    (``problem`` holds both); ``finding`` is the problem without it, for a caller whose way out
    is another (a command's own option, or none)."""

    def __init__(self, parameter, problem, remedy=None):
        self.parameter = str(parameter)
        self.finding = str(problem)
        self.remedy = remedy
        super().__init__(parameter, problem if remedy is None else f"{problem}: {remedy}")


def json_syntax(e):
    """A JSONDecodeError ``e`` as the words after "not valid JSON": its message and where,
    "Unterminated string starting at line 2, column 7" (some of Python's messages end in "at",
    which the position then completes)."""
    msg = e.msg[:-3] if e.msg.endswith(" at") else e.msg
    return f"{msg} at line {e.lineno}, column {e.colno}"


def is_integer(v):
    """Whether ``v`` is an integer argument: a Python or NumPy integer, never a bool (True
    would silently mean 1)."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def checked_flag(flag, name):
    """``flag`` as a bool: True or False (NumPy's too), else ParameterError naming it (a string
    such as "no" would read as True)."""
    if not isinstance(flag, (bool, np.bool_)):
        raise ParameterError(name, f"must be True or False, got {shown(flag)}")
    return bool(flag)


def cut_short(text, limit):
    """``text`` for a message, cut to ``limit`` characters with "..." where it is longer: an
    error is one line."""
    return text if len(text) <= limit else text[:limit - 3] + "..."


def shown(v, limit=40):
    """``repr(v)`` for a message, cut short: a 400-digit number is not worth printing."""
    try:
        text = repr(v)
    except ValueError:                  # an int beyond Python's digit limit for str()
        return f"an integer of about {int(v.bit_length() * 0.30103)} digits"
    return cut_short(text, limit)
