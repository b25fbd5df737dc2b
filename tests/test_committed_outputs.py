"""A run's last set of outputs, once in place, is a success: a signal as that set is renamed
into place, or between it and the report, gives exit status 0 with every output there, for
every command that writes files. And what build writes (its tree and its dumps) appears
whole or not at all."""
import json
import os
import signal
import time
from argparse import Namespace
from contextlib import contextmanager

import numpy as np
import pytest

import hwrt.cli as cli
from hwrt.cli import BENCH_COMMITS, BENCH_OPTIONS, BENCH_REPORTS, main

TETRA_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
# tiny cells: a study run at this size, then resumed by the command line
STUDY_SIZE = {"width": 16, "height": 12}


def call(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@contextmanager
def late_signals(monkeypatch, trigger):
    """SIGINT as the file named ``trigger`` (one of the run's last set) is renamed into place,
    and again just before the report is printed. Yields the moments that were signalled."""
    signalled = []
    real_replace, real_emit = os.replace, cli._emit

    def replace(src, dst):
        real_replace(src, dst)
        if os.path.basename(dst) == trigger:
            signalled.append("renames")
            os.kill(os.getpid(), signal.SIGINT)

    def emit(*args):
        signalled.append("report")
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)                       # Python acts on the signal here unless ignored
        real_emit(*args)

    with monkeypatch.context() as m:
        m.setattr(os, "replace", replace)
        m.setattr(cli, "_emit", emit)
        yield signalled


@pytest.fixture
def tetra(tmp_path):
    p = tmp_path / "tetra.obj"
    p.write_text(TETRA_OBJ)
    return p


@pytest.fixture(scope="module")
def mesh_dir(tmp_path_factory):
    import trimesh
    from scenes.meshes import sphere
    d = tmp_path_factory.mktemp("meshes")
    tris = sphere(6, 12)
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                    process=False).export(d / "ball.ply")
    return d


def _study_args(mesh_dir, out, **more):
    return Namespace(quick=True, repeat=1, fresh=False, meshes=[], mesh_dir=str(mesh_dir),
                     out_dir=str(out), scheduler=None, **STUDY_SIZE, **more)


# Each command that writes files: (argv, the file whose rename is signalled, the output
# directory, the files the run leaves there). A resumable command that runs its cells on a
# cluster runs them here first, in this process, so that the command line only resumes them
# (seconds, no cluster) and leaves the files the first run left (None).
def _build(tmp_path, tetra, mesh_dir):
    # the tree's files are renamed first: a signal at a dump's rename, after them, must
    # leave the dumps' files in place all the same
    out = tmp_path / "out"
    return (["build", tetra, "--out", out / "tree", "--dump-aabbs", out / "boxes.bin",
             "--dump-handoff", out / "handoff.bin"], "boxes.bin", out,
            ["boxes.bin", "handoff.bin", "handoff.bin.json", "tree.indices", "tree.json",
             "tree.nodes"])


def _explore(tmp_path, tetra, mesh_dir):
    from hwrt import explore as ex
    out = tmp_path / "out"
    mesh = mesh_dir / "ball.ply"
    ex.explore([str(mesh)], {"w": [2, 4]}, str(out), use_dask=False, progress=False)
    return (["explore", mesh, "--grid", "w=2,4", "--out-dir", out], "explore.csv", out, None)


def _tti(tmp_path, tetra, mesh_dir):
    from hwrt import study
    out = tmp_path / "out"
    study.bench_tti(_study_args(mesh_dir, out, spp=1, max_depth=2, accel=["bvh"]),
                    use_dask=False, progress=False)
    return (["bench", "tti", "--quick", "--width", 16, "--height", 12, "--max-depth", 2,
             "--accel", "bvh", "--mesh-dir", mesh_dir, "--out-dir", out], "tti.csv", out, None)


def _accuracy(tmp_path, tetra, mesh_dir):
    from hwrt import study
    out = tmp_path / "out"
    study.bench_accuracy(_study_args(mesh_dir, out), use_dask=False, progress=False)
    return (["bench", "accuracy", "--quick", "--width", 16, "--height", 12,
             "--out-dir", out], "accuracy.csv", out, None)


def _bench_render(tmp_path, tetra, mesh_dir):
    out = tmp_path / "out"
    return (["bench", "render", "cornell", "--repeat", 1, "--width", 8, "--height", 8,
             "--spp", 1, "--out-dir", out], "render.json", out, ["render.json", "render.md"])


def _bench_report(tmp_path, tetra, mesh_dir):
    out = tmp_path / "out"
    return (["bench", "build", tetra, "--repeat", 1, "--out-dir", out], "build.md", out,
            ["build.json", "build.md"])


def _bench_animation(tmp_path, tetra, mesh_dir):
    from hwrt.animate import BENCH_FILES
    out = tmp_path / "out"
    return (["bench", "animation", "--quick", "--frames", 1, "--width", 8, "--height", 8,
             "--accel", "bvh", "--out-dir", out], BENCH_FILES["csv"], out,
            sorted(BENCH_FILES.values()))


def _animate(tmp_path, tetra, mesh_dir):
    from hwrt.animate import CSV_NAME, PREVIEW_NAME, STATE_NAME
    out = tmp_path / "out"
    return (["animate", "flythrough", "--frames", 2, "--width", 8, "--height", 8, "-o", out],
            CSV_NAME, out, sorted([CSV_NAME, PREVIEW_NAME, STATE_NAME, "frame_0000.exr",
                                   "frame_0001.exr"]))


def _bench_model(tmp_path, tetra, mesh_dir):
    from hwrt.bench import MODEL_FIGURES
    out = tmp_path / "out"
    return (["bench", "model", tetra, "--out-dir", out], "model.md", out,
            sorted(["model.md", "model.json", *MODEL_FIGURES]))


RUNS = {"build": _build, "explore": _explore, "bench tti": _tti, "bench accuracy": _accuracy,
        "bench render": _bench_render, "bench build": _bench_report,
        "bench animation": _bench_animation, "bench model": _bench_model, "animate": _animate}


# bench accuracy writes its files through the study's writer (``study._write_outputs``), as
# bench tti does: its case (48 s, most of it the study's cells) runs with the slow tests
@pytest.mark.parametrize("command", [pytest.param(c, marks=pytest.mark.slow)
                                     if c == "bench accuracy" else c for c in RUNS])
def test_a_signal_once_the_last_outputs_are_written_does_not_fail_the_run(
        command, tmp_path, tetra, mesh_dir, capsys, monkeypatch):
    argv, trigger, out, expected = RUNS[command](tmp_path, tetra, mesh_dir)
    before = {p.name: p.stat().st_ino for p in out.iterdir()} if out.exists() else {}
    expected = sorted(before) if expected is None else expected
    with late_signals(monkeypatch, trigger) as signalled:
        rc, stdout, err = call(capsys, *argv)
    assert rc == 0 and "interrupted" not in err, err
    assert signalled == ["renames", "report"]
    names = sorted(p.name for p in out.iterdir())
    assert not [n for n in names if n.startswith(".tmp-")]
    assert names == expected
    # the signalled set was written by this run, not left from the preparation
    assert (out / trigger).stat().st_ino != before.get(trigger)


def test_each_benchmark_with_an_out_dir_is_listed_as_a_report_or_a_committer_not_both():
    writers = [w for w, opts in BENCH_OPTIONS.items() if "out_dir" in opts]
    assert sorted(writers) == sorted(BENCH_REPORTS + BENCH_COMMITS)
    assert not set(BENCH_REPORTS) & set(BENCH_COMMITS)


@pytest.mark.parametrize("failure,code", [(OSError(28, "No space left on device"), 1),
                                          (KeyboardInterrupt(), 130)])
def test_build_writes_its_tree_and_dumps_whole_or_not_at_all(tmp_path, tetra, capsys,
                                                             monkeypatch, failure, code):
    """The tree's file fails (a full disk) or is interrupted as it is written: no dump is left
    without the tree."""
    import hwbvh.files as files
    real_mkstemp = files.tempfile.mkstemp

    def mkstemp(*args, **kwargs):
        if kwargs.get("suffix") == ".indices":
            raise failure
        return real_mkstemp(*args, **kwargs)
    monkeypatch.setattr(files.tempfile, "mkstemp", mkstemp)
    out = tmp_path / "out"
    rc, stdout, err = call(capsys, "build", tetra, "--out", out / "tree",
                           "--dump-aabbs", out / "boxes.bin", "--dump-handoff", out / "handoff.bin")
    assert rc == code and stdout == "", err
    assert not out.exists() or list(out.iterdir()) == []


def test_a_signal_as_the_run_turns_to_ignoring_signals_does_not_fail_it(tmp_path, tetra, capsys,
                                                                        monkeypatch):
    """SIGINT on entry to ``_succeeded``, after the last renames and before it ignores
    signals: the outputs are in place, so the run has succeeded."""
    real, signalled = cli._succeeded, []

    def succeeded(args):
        if not signalled:
            signalled.append(True)
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)                   # Python acts on the signal here
        real(args)
    monkeypatch.setattr(cli, "_succeeded", succeeded)
    out = tmp_path / "out"
    rc, stdout, err = call(capsys, "build", tetra, "--out", out / "tree")
    assert signalled and rc == 0 and "interrupted" not in err, err
    assert sorted(p.name for p in out.iterdir()) == ["tree.indices", "tree.json", "tree.nodes"]


def test_build_makes_each_file_as_it_writes_it(tmp_path, tetra, capsys, monkeypatch):
    """The tree and the dumps are one set, but their bytes are not all in memory at once:
    each payload is made once its temporary file exists, in the order they are written."""
    import hwbvh.api
    import hwbvh.files as files
    import hwbvh.primitives as primitives
    events = []
    real_mkstemp, real_pack_records = files.tempfile.mkstemp, primitives.pack_records
    real_pack_indices = hwbvh.api.pack_indices

    def mkstemp(*args, **kwargs):
        events.append("file " + kwargs["suffix"])
        return real_mkstemp(*args, **kwargs)

    def pack(real, name):
        def made(*args, **kwargs):
            events.append(name)
            return real(*args, **kwargs)
        return made
    monkeypatch.setattr(files.tempfile, "mkstemp", mkstemp)
    monkeypatch.setattr(primitives, "pack_records", pack(real_pack_records, "records"))
    monkeypatch.setattr(hwbvh.api, "pack_indices", pack(real_pack_indices, "indices"))
    out = tmp_path / "out"
    rc, stdout, err = call(capsys, "build", tetra, "--out", out / "tree", "--dump-aabbs",
                           out / "boxes.bin", "--dump-handoff", out / "handoff.bin", "--json")
    assert rc == 0, err
    assert events == ["file .nodes", "file .indices", "indices", "file .json",
                      "file .bin", "records", "file .bin", "records", "file .json"]
    from hwbvh.api import tree_paths
    assert json.loads(stdout)["outputs"] == tree_paths(str(out / "tree")) + [
        str(out / "boxes.bin"), str(out / "handoff.bin"), str(out / "handoff.bin.json")]
