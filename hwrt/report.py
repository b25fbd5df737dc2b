"""What a generated docs page carries besides its tables: the line it opens with (the command
that made it, so that a reader can make the page again) and the figures written with it; and
the width of a table's name column."""
import os
import shlex


def command_of(args):
    """The ``hwrt`` command line of a parsed CLI call, or None for a call from Python; led by
    the environment variables its results depend on (``HWRT_MESHES=... hwrt bench build``),
    so that the line makes them again."""
    argv = getattr(args, "argv", None)
    if argv is None:
        return None
    env = "".join(f"{k}={shlex.quote(v)} " for k, v in getattr(args, "environment", {}).items())
    return env + "hwrt " + " ".join(shlex.quote(a) for a in argv)


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


def with_figures(files):
    """A set of output files ((path, text or bytes) pairs) with its ``.md`` page ending in a
    section that shows every ``.png`` of the set (written beside it), so that the figures are
    found where the tables are."""
    pngs = [os.path.basename(path) for path, _ in files if path.endswith(".png")]
    if not pngs:
        return files
    section = "\n## Figures\n\n" + "".join(
        f"![{os.path.splitext(name)[0].replace('_', ' ')}]({name})\n\n" for name in pngs)
    return [(path, data.rstrip("\n") + "\n" + section if path.endswith(".md") else data)
            for path, data in files]


def name_width(names, least):
    """The width of a text table's column of ``names``: ``least``, or wider for a long name
    (a mesh named by its path when two files share a stem), two spaces past the longest, so that
    the columns after it stay aligned."""
    return max([least] + [len(str(n)) + 2 for n in names])
