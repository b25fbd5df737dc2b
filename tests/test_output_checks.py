"""check_outputs / check_output_dir: the same refusals for any number of outputs, in time linear
in their number (an animation names one output per frame, up to MAX_FRAMES)."""
import os
import signal
import time

import pytest

from hwbvh.errors import InputError
from hwbvh.files import check_output_dir, check_outputs, write_files

FRAMES = 20_000
# a guard against quadratic work, not a benchmark: linear checking takes a fraction of this,
# pairwise comparison of 20,000 paths takes minutes
BOUND_S = 5.0


@pytest.fixture
def deadline():
    """Fail a test still running after BOUND_S seconds, rather than waiting for it."""
    def expired(signum, frame):
        raise AssertionError(f"still checking after {BOUND_S:g} s")
    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, BOUND_S)
    yield
    signal.setitimer(signal.ITIMER_REAL, 0)
    signal.signal(signal.SIGALRM, previous)


def frame_names(n):
    return [f"frame_{k:06d}.exr" for k in range(n)]


def test_many_frames_are_checked_in_linear_time(tmp_path, deadline):
    start = time.perf_counter()
    check_output_dir(tmp_path / "renders", frame_names(FRAMES) + ["timings.json"],
                     inputs=[__file__])
    check_outputs([tmp_path / n for n in frame_names(FRAMES)])
    assert time.perf_counter() - start < BOUND_S
    assert not os.listdir(tmp_path)           # the probes leave nothing behind


def test_a_duplicate_at_the_end_of_many_frames_is_still_found(tmp_path, deadline):
    names = frame_names(FRAMES) + ["./frame_000007.exr"]
    with pytest.raises(InputError, match="is named twice as an output"):
        check_output_dir(tmp_path, names)


def test_two_spellings_of_one_existing_file_are_one_file(tmp_path):
    a = tmp_path / "a.exr"
    a.write_bytes(b"x")
    os.link(a, tmp_path / "hard.exr")
    os.symlink(a, tmp_path / "soft.exr")
    for other in ("hard.exr", "soft.exr", "sub/../a.exr"):
        (tmp_path / "sub").mkdir(exist_ok=True)
        with pytest.raises(InputError) as e:
            check_outputs([a, tmp_path / other])
        assert str(e.value) == f"{tmp_path / other}: is named twice as an output"
        with pytest.raises(InputError) as e:
            check_outputs([tmp_path / other], inputs=[a])
        assert str(e.value) == (f"{tmp_path / other}: is an input of this run ({a}); "
                                "an output may not overwrite an input")


def test_an_unwritable_directory_names_each_output_given(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root writes anywhere")
    d = tmp_path / "locked"
    d.mkdir()
    d.chmod(0o500)
    try:
        with pytest.raises(InputError) as e:
            check_outputs([tmp_path / "ok.exr", d / "x.exr", d / "y.exr"])
        assert str(e.value).startswith(f"{d / 'x.exr'}: cannot create files in {d}")
    finally:
        d.chmod(0o700)


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_a_directory_that_cannot_be_made_is_named_with_the_place_that_refuses_it():
    """/proc takes no new files, for root too: the message names the directory the output
    needs, not only the nearest one that exists."""
    out = "/proc/no-such-hwrt-dir/sub/x.exr"
    with pytest.raises(InputError) as e:
        check_outputs([out])
    assert str(e.value).startswith(f"{out}: cannot create the directory /proc/no-such-hwrt-dir/sub: "
                                   "/proc takes no new files (")
    with pytest.raises(InputError) as e:
        check_output_dir("/proc/no-such-hwrt-dir")
    assert "cannot create the directory /proc/no-such-hwrt-dir: /proc takes no new files" in str(e.value)


def test_a_device_or_pipe_as_an_output_is_refused_and_left_as_it_is(tmp_path):
    """Outputs are written beside their path and renamed over it: a named pipe (or a device
    such as /dev/full) would be replaced by a regular file, so it is refused before any work."""
    import stat
    import subprocess
    import sys
    fifo = tmp_path / "pipe.bin"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="is not a regular file"):
        check_outputs([tmp_path / "fine.bin", fifo])
    mesh = tmp_path / "t.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r = subprocess.run([sys.executable, "-m", "hwrt", "build", str(mesh), "--dump-aabbs",
                        str(fifo)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stderr.splitlines() == [
        f"hwrt: error: --dump-aabbs {fifo}: is not a regular file (a device, pipe or socket); "
        f"give a file path"], r.stderr
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    link = tmp_path / "link.bin"                   # a link to a regular file is one
    (tmp_path / "target.bin").write_bytes(b"")
    link.symlink_to(tmp_path / "target.bin")
    check_outputs([link])


def test_an_output_error_names_the_output_option_though_an_input_option_holds_the_path(
        tmp_path, capsys):
    """animate --mesh a.ply -o a.ply: the output is what cannot be written there, so the error
    names -o/--output, not --mesh."""
    import trimesh
    from hwrt.cli import main
    mesh = tmp_path / "a.ply"
    trimesh.creation.box().export(mesh)
    assert main(["animate", "exploding", "--mesh", str(mesh), "-o", str(mesh), "--frames", "2",
                 "--width", "8", "--height", "6"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"hwrt: error: --output {mesh}: exists and is not a directory"]


def test_a_path_is_checked_and_written_as_the_system_resolves_it(tmp_path, monkeypatch):
    """``new/sub/../x`` needs ``new/sub`` (the system takes ``..`` after it), which the writer
    makes; a directory part that is a file, or a symbolic link to nothing, is refused before
    any work, naming it."""
    monkeypatch.chdir(tmp_path)
    os.symlink(tmp_path / "nowhere", "dangling")
    (tmp_path / "plain").write_text("")
    check_outputs(["new/sub/../x.txt"])
    write_files([("new/sub/../x.txt", "x")])
    assert (tmp_path / "new" / "x.txt").read_text() == "x" and (tmp_path / "new" / "sub").is_dir()
    for out, problem in [("dangling/x.txt", "dangling is a symbolic link to "),
                         ("plain/../y.txt", "cannot create a directory under plain: it is a file")]:
        with pytest.raises(InputError) as e:
            check_outputs([out])
        assert problem in str(e.value) and str(e.value).startswith(out)
    for directory, problem in [("dangling", "dangling: is a symbolic link to "),
                               ("dangling/run", "dangling is a symbolic link to ")]:
        with pytest.raises(InputError, match=problem):
            check_output_dir(directory, ["frame.exr"])
    assert sorted(os.listdir(tmp_path)) == ["dangling", "new", "plain"]
