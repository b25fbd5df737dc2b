"""The line a generated docs page opens with: the command that made it, so that a reader can
make the page again."""
import shlex


def command_of(args):
    """The ``hwrt`` command line of a parsed CLI call, or None for a call from Python."""
    argv = getattr(args, "argv", None)
    return None if argv is None else "hwrt " + " ".join(shlex.quote(a) for a in argv)


def made_by(command):
    """The line 'Made by `COMMAND`.', or '' without a command."""
    return f"Made by `{command}`." if command else ""


def made_by_lines(command):
    """``made_by`` as lines of a page joined by newlines (the line and a blank line), or []."""
    line = made_by(command)
    return [line, ""] if line else []


def made_by_block(command):
    """``made_by`` as a paragraph (the line and a blank line), or ''."""
    return "".join(line + "\n" for line in made_by_lines(command))
