"""Errors that name the input and the problem; the CLI turns them into exit status 2."""


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
    spells it (``leaf_size``); a command line reports its own option for it (``--leaf-size``)."""

    def __init__(self, parameter, problem):
        self.parameter = str(parameter)
        super().__init__(parameter, problem)
