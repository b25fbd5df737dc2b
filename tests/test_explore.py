"""hwrt explore: the grid, the fronts, shared builds, resumable cells, bad input at the command
line, and a Dask cluster that loses a worker mid-run yet returns the single-process result."""
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import trimesh

from hwbvh.errors import ParameterError
from hwrt import explore as ex
from scenes.meshes import bumpy_sphere, random_soup


def write_mesh(path, tris):
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3),
                    process=False).export(path)
    return str(path)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    return [write_mesh(d / "soup.ply", random_soup(3000, seed=2)),
            write_mesh(d / "sphere.ply", bumpy_sphere(12_000))]


GRID = {"w": [2, 4, 8], "tsize": [2, 8], "leaf_size": [4, 16]}


def run_cli(*args, cwd=None):
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "hwrt.cli", "explore", *map(str, args)],
                       capture_output=True, text=True, timeout=300, cwd=cwd)
    return r, time.perf_counter() - t


# --------------------------------------------------------------------------------------
def test_grid_parsing_and_its_errors():
    assert ex.parse_grid(["w=2,4", "clock-mhz=250,500.5"]) == {"w": [2, 4], "clock_mhz": [250.0, 500.5]}
    for bad, name in ((["w="], "w"), (["w=2,,4"], "w"), (["bogus=1"], "grid"), (["w2"], "grid"),
                      (["w=2", "w=4"], "w"), (["w=2,2"], "w"), (["bins=1.5"], "bins"),
                      (["clock_mhz=inf"], "clock_mhz"), (["w=4_0"], "w"),
                      (["clock_mhz=1_000"], "clock_mhz"), (["w=0x4"], "w"),
                      ([f"psize={','.join(map(str, range(1024, 1424)))}",
                        f"clock_mhz={','.join(map(str, range(1, 301)))}"], "grid")):
        with pytest.raises(ParameterError) as e:
            ex.parse_grid(bad)
        assert e.value.parameter == name, bad


def test_configurations_cover_the_grid_and_always_hold_the_presets():
    cfgs = ex.configurations(GRID)
    assert len(cfgs) == 3 * 2 * 2 + 1                 # HWBVH-C is in the grid, HWBVH-HP is added
    names = [n for _, n in cfgs if n]
    assert sorted(names) == ["HWBVH-C", "HWBVH-HP"]
    assert all(p.bins == 16 and p.psize == 2048 for p, n in cfgs if not n)
    for grid, knob in (({"bins": [8, 17]}, "bins"), ({"w": [0]}, "w"), ({"tsize": [3]}, "tsize"),
                       ({"clock_mhz": [0.0]}, "clock_mhz"), ({"psize": [1 << 23], "w": [4]}, "psize")):
        with pytest.raises(ParameterError) as e:
            ex.configurations(grid)
        assert e.value.parameter == knob


def test_labels_name_the_presets_and_show_the_knobs_that_vary():
    configs = [dict(ex.config_of(p), preset=n) for p, n in ex.configurations({"w": [2, 4]})]
    lab = ex.labeller({"configs": configs})
    by_name = {c["preset"]: lab(c) for c in configs if c["preset"]}
    assert by_name["HWBVH-C"].startswith("HWBVH-C: ")
    assert by_name["HWBVH-HP"].startswith("HWBVH-HP: ")
    plain = [lab(c) for c in configs if not c["preset"]]
    assert plain and not any(":" in x for x in plain)
    # w varies in the grid; the presets add the knobs they set otherwise (HWBVH-HP's clock)
    assert all("w" in x.split(": ")[-1] for x in plain + list(by_name.values()))
    assert len(set(plain) | set(by_name.values())) == len(configs)     # no two alike


def test_pareto_front_and_gaps():
    pts = [(1, 9), (2, 5), (2, 7), (3, 5), (4, 1), (4, 1), (5, 0.5), (6, 3)]
    assert ex.pareto_front(pts) == [0, 1, 4, 5, 6]
    front = [pts[i] for i in ex.pareto_front(pts)]
    assert ex.gaps((3, 5), front) == {"y_ratio": 1.0, "area_ratio": 1.5}
    assert ex.gaps((6, 3), front) == {"y_ratio": 6.0, "area_ratio": 1.5}
    assert ex.gaps((4, 1), front) == {"y_ratio": 1.0, "area_ratio": 1.0}


def test_in_process_exploration_fronts_and_shared_builds(meshes, monkeypatch):
    from hwbvh import builder
    builds = []
    real = builder.build_canonical
    monkeypatch.setattr(builder, "build_canonical", lambda *a, **k: builds.append(k) or real(*a, **k))
    ex._TREES.clear()
    r = ex.explore(meshes, GRID, use_dask=False, progress=False)
    # one build per (mesh, leaf size): w, Tsize and the presets' builders and clock share it
    assert sorted((k["leaf_size"], k["bins"]) for k in builds) == [(4, 16), (4, 16), (16, 16), (16, 16)]
    assert r["cells"] == len(r["rows"]) == 13 * 2 == r["computed"]
    for row in r["rows"]:
        assert row["energy_joules"] == row["seconds"] * row["active_power_w"]
        assert row["footprint_bytes"] == 54 * row["triangles"]
    # every front point is undominated, every other point is dominated by a front point
    for group in r["pareto"]:
        for front_name, metric in (("time_area", "seconds"), ("energy_area", "energy_joules")):
            rows = [x for x in r["rows"] if x["mesh"] == "sphere"
                    and x["config"]["leaf_size"] == group["leaf_size"]]
            front = [(p["area_mm2"], p[metric]) for p in group[front_name]["sphere"]]
            pts = [(x["area_mm2"], x[metric]) for x in rows]
            for p in pts:
                dominated = any(a <= p[0] and y <= p[1] and (a, y) != p for a, y in front)
                assert (p in front) != dominated or p in front
            for a, y in front:
                assert not any(b <= a and z <= y and (b, z) != (a, y) for b, z in pts)
    scopes = {b["scope"] for b in r["best"]}
    assert {"soup", "sphere", "small (< 50k triangles)"} <= scopes
    assert {g["preset"] for g in r["preset_gaps"]} == {"HWBVH-C", "HWBVH-HP"}
    json.dumps(r, allow_nan=False)


def test_cells_resume_after_an_interruption(meshes, tmp_path):
    out = tmp_path / "out"
    grid = {"w": [2, 4], "tsize": [2, 8], "leaf_size": [4, 8]}
    first = ex.explore(meshes, grid, out, use_dask=False, progress=False)
    assert first["computed"] == first["cells"] and len(first["files"]) == 6
    assert first["files"][-1] == str(out / ex.CELLS_NAME)      # what a rerun resumes from
    for name in ex.OUTPUT_NAMES:
        assert (out / name).exists(), name
    again = ex.explore(meshes, grid, out, use_dask=False, progress=False)
    assert again["computed"] == 0 and again["rows"] == first["rows"]
    # a line cut by an interruption: that cell alone runs again
    cells = out / ex.CELLS_NAME
    data = cells.read_bytes()
    cells.write_bytes(data[:-40])
    third = ex.explore(meshes, grid, out, use_dask=False, progress=False)
    assert third["computed"] == 1 and third["rows"] == first["rows"]
    # a number edited to NaN (our lines write null): that cell runs again, not into the CSV
    lines = cells.read_text().splitlines()
    row = json.loads(lines[0])
    assert isinstance(row["seconds"], float)
    lines[0] = lines[0].replace(f'"seconds": {json.dumps(row["seconds"])}', '"seconds": NaN')
    assert "NaN" in lines[0]
    cells.write_text("\n".join(lines) + "\n")
    fourth = ex.explore(meshes, grid, out, use_dask=False, progress=False)
    assert fourth["computed"] == 1 and fourth["rows"] == first["rows"]
    assert "nan" not in (out / "explore.csv").read_text().lower()
    # rows edited or left by another version: a field unknown, one missing, a number become
    # text or a bool: those cells run again
    lines = cells.read_text().splitlines()[1:]            # the NaN line is stale now
    rows = [json.loads(x) for x in lines[:4]]
    rows[0]["note"] = 1
    del rows[1]["sah_cost"]
    rows[2]["seconds"] = "fast"
    rows[3]["cycles"] = True
    cells.write_text("\n".join([json.dumps(r) for r in rows] + lines[4:]) + "\n")
    fifth = ex.explore(meshes, grid, out, use_dask=False, progress=False)
    assert fifth["computed"] == 4 and fifth["rows"] == first["rows"]
    fresh = ex.explore(meshes, grid, out, use_dask=False, progress=False, fresh=True)
    assert fresh["computed"] == fresh["cells"]
    assert len(cells.read_text().splitlines()) == fresh["cells"]
    # the thesis' Figs. 4.2-4.3 are the subtree builder's alone (``hwrt bench model``), not
    # drawn from a grid of whole-scene builds
    drawn = {os.path.basename(p) for p in fresh["files"]}
    assert drawn == {*ex.OUTPUT_NAMES, ex.CELLS_NAME} and not any(n.startswith("fig4") for n in drawn)


def test_meshes_are_named_as_the_benchmarks_name_them(tmp_path):
    """A stem two files share names each by its path (the benchmarks' rule); the same file
    given twice is refused, its rows would be one."""
    from hwbvh.errors import InputError
    paths = []
    for rel, n in (("a/s.ply", 100), ("b/s.ply", 120), ("a/t.obj", 80)):
        (tmp_path / rel).parent.mkdir(exist_ok=True)
        paths.append(write_mesh(tmp_path / rel, random_soup(n, seed=n)))
    assert [(m["name"], m["triangles"]) for m in ex.mesh_specs(paths)] == [
        (paths[0], 100), (paths[1], 120), ("t", 80)]
    with pytest.raises(InputError, match="given twice"):
        ex.mesh_specs([paths[2], paths[2]])
    copy = tmp_path / "copy.obj"                # cells are keyed by contents: refused too
    copy.write_bytes(open(paths[2], "rb").read())
    with pytest.raises(InputError) as e:
        ex.mesh_specs([paths[2], copy])
    assert str(e.value) == f"{copy}: has the same contents as {paths[2]}: give one of them"
    for bad, problem in ((tmp_path / "none.ply", "no such file"),
                         (tmp_path / "a", "is a directory, not a mesh file")):
        with pytest.raises(InputError) as e:
            ex.mesh_specs([bad])
        assert str(e.value) == f"{bad}: {problem}"


@pytest.mark.parametrize("args,message", [
    (["--grid", "w="], "--grid: w: empty value"),
    (["--grid", "bogus=1"], "unknown knob 'bogus'"),
    (["--grid", "bins=17"], "--grid: bins: must be an integer within 2..16"),
    (["--grid", "w=0"], "--grid: w: must be an integer within 1..64"),
    (["--grid", "w=1", "--grid", "psize=2"],
     "--grid: psize: w * psize = 2 is below the leaf size 4: a subtree builder must hold a leaf"),
    (["--grid", "w=2", "--scheduler", "tcp://127.0.0.1:9"], "--scheduler: no Dask scheduler answers"),
    (["--grid", "w=2", "--scheduler", "garbage"],
     "--scheduler: 'garbage' is not a scheduler address (missing port number"),
    (["--grid", "w=2", "--scheduler", "tcp://127.0.0.1:8786/"],
     "is not a scheduler address (port '8786/' is not a number; e.g. tcp://HOST:8786)"),
    (["--grid", "w=2", "--scheduler", "tcp://127.0.0.1:99999"],
     "is not a scheduler address (port 99999 is not in 1..65535; e.g. tcp://HOST:8786)"),
    (["--grid", "w=2", "--scheduler", "inproc://x"],
     "no Dask scheduler answers at 'inproc://x' within 5 s (an inproc address names a "
     "scheduler of this process, and none has it)"),
    (["--grid", "w=2", "--scheduler", "http://127.0.0.1:8786"], "its scheme 'http' is not one"),
])
def test_cli_bad_input_one_line_exit_2_no_output(meshes, tmp_path, args, message):
    out = tmp_path / "out"
    r, seconds = run_cli(meshes[0], *args, "--out-dir", out)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and message in r.stderr, r.stderr
    assert not out.exists()
    from hwrt.cluster import CONNECT_TIMEOUT_S
    assert seconds < CONNECT_TIMEOUT_S + 30           # fails fast: no wait for the work


def test_a_scheduler_without_workers_is_a_one_line_error_not_a_wait(meshes, tmp_path):
    """Cells sent to a scheduler that no worker has joined would wait for ever: explore waits
    a few seconds for one, then names the option."""
    from distributed import LocalCluster
    from hwrt.cluster import CONNECT_TIMEOUT_S

    with LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=None,
                      silence_logs=50) as cluster:
        out = tmp_path / "out"
        r, seconds = run_cli(meshes[0], "--grid", "w=2", "--scheduler", cluster.scheduler_address,
                             "--out-dir", out)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert f"--scheduler: the Dask scheduler at {cluster.scheduler_address} has no workers" \
        in r.stderr
    assert seconds < CONNECT_TIMEOUT_S + 30 and not out.exists()


def test_cli_unwritable_out_dir(meshes, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r, _ = run_cli(meshes[0], "--grid", "w=2", "--out-dir", blocker / "sub")
    assert r.returncode == 2 and str(blocker) in r.stderr and r.stderr.count("\n") == 1
    r, _ = run_cli(meshes[0], "--grid", "w=2", "--out-dir", os.path.dirname(meshes[0]))
    assert r.returncode == 0          # a directory of inputs is fine as long as no input is replaced
    r, _ = run_cli(meshes[0], "--grid", "w=2", "--out-dir", tmp_path / "o", "--json", "--workers", "1")
    res = json.loads(r.stdout)
    assert r.returncode == 0 and res["cells"] == 3 and set(res["pareto"][0]) >= {"time_area", "energy_area"}
    row = res["rows"][0]
    for k in ("mesh", "config", "cycles", "seconds", "energy_joules", "area_mm2", "active_power_w",
              "traffic_bytes", "footprint_bytes", "sah_cost", "utilisation"):
        assert k in row


def test_dask_cluster_losing_a_worker_gives_the_single_process_result(tmp_path, monkeypatch):
    """Two worker processes; one is killed while cells run. Dask reruns its cells elsewhere and
    the result equals, bit for bit, the same exploration in one process."""
    from distributed import Client, LocalCluster

    d = tmp_path / "m"
    d.mkdir()
    meshes = [write_mesh(d / "a.ply", bumpy_sphere(60_000)), write_mesh(d / "b.ply", random_soup(30_000, seed=7))]
    grid = {"w": [2, 4, 8, 16], "tsize": [2, 4, 8, 16], "psize": [1024, 2048], "subtree_builders": [1, 2]}
    monkeypatch.setattr(ex, "BATCH_CONFIGS", 4)
    reference = ex.explore(meshes, grid, use_dask=False, progress=False)
    out = tmp_path / "out"
    cells = out / ex.CELLS_NAME
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=50) as cluster, Client(cluster) as watcher:
        killed = {}

        def kill_one_when_cells_arrive():
            deadline = time.time() + 120
            while time.time() < deadline:
                n = len(cells.read_text().splitlines()) if cells.exists() else 0
                if n >= 8:
                    pids = watcher.run(os.getpid)
                    killed["lines"] = n
                    os.kill(next(iter(pids.values())), signal.SIGKILL)
                    return
                time.sleep(0.005)

        t = threading.Thread(target=kill_one_when_cells_arrive)
        t.start()
        result = ex.explore(meshes, grid, out, scheduler=cluster.scheduler_address, progress=False)
        t.join()
    assert killed and killed["lines"] < result["cells"], "the worker was killed after the run"
    assert result["computed"] == result["cells"] == reference["cells"]
    assert result["rows"] == reference["rows"]
    assert result["pareto"] == reference["pareto"] and result["best"] == reference["best"]
    # every cell was saved once it finished, so a re-run resumes all of them
    assert len({json.loads(x)["key"] for x in cells.read_text().splitlines()}) == result["cells"]
    again = ex.explore(meshes, grid, out, use_dask=False, progress=False)
    assert again["computed"] == 0 and again["rows"] == reference["rows"]


def _cell_threads():
    import numba
    return numba.get_num_threads()


def test_embedded_cluster_cells_get_the_threads_asked_for():
    """A worker imports Numba before its cluster's environment applies; the cell must still
    run with ``threads_per_cell`` Numba threads, not the worker's default."""
    from hwrt.cluster import dask_client, run_cells

    import dask
    got = {}
    with dask.config.set({"distributed.comm.timeouts.connect": "17s"}):
        with dask_client(workers=1, threads_per_cell=1) as client:
            run_cells([("one", _cell_threads, ())], got.__setitem__, client=client,
                      progress=False)
        # the cluster's own Dask settings end with it
        assert dask.config.get("distributed.comm.timeouts.connect") == "17s"
    assert got == {"one": 1}


def test_ctrl_c_on_the_embedded_cluster_prints_one_line_and_leaves_resumable_cells(meshes, tmp_path):
    """Ctrl-C at a terminal signals every process of the foreground group, the embedded
    cluster's workers too: they must not die each with its own traceback. One line, exit 130,
    no worker left behind, and the cells saved so far resume."""
    out = tmp_path / "out"
    cells = out / ex.CELLS_NAME
    p = subprocess.Popen([sys.executable, "-m", "hwrt.cli", "explore", meshes[1], "--workers", "2",
                          "--out-dir", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, start_new_session=True)
    try:
        deadline = time.time() + 60
        while not (cells.exists() and cells.stat().st_size) and p.poll() is None:
            assert time.time() < deadline, "no cell finished"
            time.sleep(0.02)
        assert p.poll() is None, "the run ended before it could be interrupted"
        workers = subprocess.run(["pgrep", "-g", str(p.pid)], capture_output=True,
                                 text=True).stdout.split()
        os.killpg(p.pid, signal.SIGINT)             # what a terminal's Ctrl-C does
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 130 and err == "hwrt: interrupted\n", err
    assert len(workers) > 1, "the cluster's processes were not seen"
    deadline = time.time() + 10                     # the resource tracker exits as it sees EOF
    while (left := subprocess.run(["pgrep", "-a", "-g", str(p.pid)], capture_output=True,
                                  text=True).stdout) and time.time() < deadline:
        time.sleep(0.1)
    assert left == "", f"processes left behind: {left}"
    assert ex._CellStore(cells, fresh=False).done          # a rerun resumes these


def test_a_run_whose_workers_are_all_lost_says_it_waits_for_one():
    """Dask waits, silently, for a worker when a run has lost them all: the run says so once
    on stderr and goes on when one joins."""
    from distributed import Client, LocalCluster
    from hwrt.cluster import workers_watched

    lines = []
    with LocalCluster(n_workers=1, processes=False, protocol="tcp", dashboard_address=None,
                      silence_logs=50) as cluster, Client(cluster) as client:
        with workers_watched(client, every=0.05, say=lines.append):
            time.sleep(0.3)
            assert lines == []                      # a worker: nothing said
            client.retire_workers(list(client.scheduler_info()["workers"]))
            deadline = time.time() + 30
            while not lines and time.time() < deadline:
                time.sleep(0.05)
            time.sleep(0.3)                         # said once, not at every check
    assert lines == [f"hwrt: the Dask scheduler at {cluster.scheduler_address} has no workers "
                     f"left; waiting for one to join (the run goes on when one does)"]


def test_a_second_exploration_into_a_directory_in_use_is_refused(tmp_path):
    """Two explorations into one directory would share (or, with fresh, remove) each other's
    saved cells: the directory is held while one runs, as an animation's is."""
    from hwbvh.errors import InputError
    from hwbvh.files import held_directory
    mesh = write_mesh(tmp_path / "soup.ply", random_soup(200, seed=2))
    out = tmp_path / "out"
    with held_directory(str(out), "explore"):             # another run, meanwhile
        with pytest.raises(InputError, match="another hwrt explore is writing into it"):
            ex.explore([mesh], {"w": [2]}, out, use_dask=False, progress=False)
        assert os.listdir(out) == []
    assert not out.exists()                                # made for it, left empty: removed
    result = ex.explore([mesh], {"w": [2]}, out, use_dask=False, progress=False)
    assert result["computed"] == result["cells"] > 0 and (out / "explore.json").exists()
