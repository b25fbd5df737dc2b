"""Errors that name the input and the problem; the CLI turns them into exit status 2."""


class InputError(ValueError):
    """Bad input: a missing or malformed file, bad coordinates, an out-of-range parameter.

    The message is one line and names the file (or argument) and the problem.
    """

    def __init__(self, source, problem):
        self.source = str(source)
        self.problem = str(problem)
        super().__init__(f"{self.source}: {self.problem}")
