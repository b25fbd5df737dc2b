"""The transaction-level timing model: conservation, monotonicity, the two regimes (one
subtree vs the upper builder), the footprint formula and the design-space trends."""
import json
import subprocess
import sys

import numpy as np
import pytest

from hwbvh.builder import build_canonical
from hwbvh.cycle_model import PRESETS, footprint_bytes, params_for, simulate, simulate_mesh, sweep
from hwbvh.errors import InputError
from hwbvh.primitives import primitive_boxes
from scenes.meshes import bumpy_sphere, random_soup


@pytest.fixture(scope="module")
def big():
    tris = bumpy_sphere(60_000)
    return tris, build_canonical(primitive_boxes(tris))


@pytest.fixture(scope="module")
def small():
    tris = random_soup(5000, seed=3)
    return tris, build_canonical(primitive_boxes(tris))


def internal_records(tree, pred):
    """Sum of counts of internal nodes satisfying pred(count)."""
    m = (tree.left >= 0) & (tree.count > 0)
    c = tree.count[m]
    return int(c[pred(c)].sum())


def test_footprint_is_table_4_2_formula():
    assert footprint_bytes(69451) == 2 * 27 * 69451
    # thesis Table 4.2: Bunny 3.57 MB (2 * 27 B * 69,451 = 3.75e6 B = 3.57 MiB)
    assert footprint_bytes(69451) / 2**20 == pytest.approx(3.57, abs=0.01)


def test_single_subtree_scene_never_starts_the_upper_builder(small):
    tris, tree = small
    r = simulate(tree, PRESETS["HWBVH-C"])
    assert not r["upper_builder"]["used"]
    assert r["traffic_bytes"]["upper_sort"] == 0
    assert r["subtree_builders"]["handoffs"] == 1
    # every primitive is partitioned once per internal level it passes
    assert r["subtree_builders"]["records_partitioned"] == internal_records(tree, lambda c: c > 0)


def test_upper_builder_traffic_is_conserved(big):
    tris, tree = big
    p = PRESETS["HWBVH-C"]
    r = simulate(tree, p)
    n = len(tris)
    cap = p.capacity
    ub = r["upper_builder"]
    assert ub["used"] and ub["nodes"] > 0
    assert ub["records_partitioned"] == internal_records(tree, lambda c: c > cap)
    handoff = r["subtree_builders"]["records_partitioned"]
    assert ub["records_partitioned"] + handoff == internal_records(tree, lambda c: c > 0)
    # traffic = AABB pass + root binning + read/write per upper pass + hand-off reads
    assert r["traffic_bytes"]["aabb"] == 24 * n
    assert r["traffic_bytes"]["upper_sort"] == 27 * n + 2 * 27 * ub["records_partitioned"] + 27 * n
    assert r["traffic_bytes"]["nodes"] == 48 * tree.stats["nodes"]
    assert r["traffic_bytes"]["indices"] == 24 * -(-n // 8)
    assert r["energy_joules"] == pytest.approx(r["seconds"] * 5.902)


def test_more_threads_more_bandwidth_more_builders_never_slower(big):
    tris, tree = big
    cyc = [simulate(tree, params_for("HWBVH-C", tsize=t))["cycles"] for t in (2, 4, 8, 16)]
    assert all(a >= b for a, b in zip(cyc, cyc[1:])), cyc
    ram = [simulate(tree, params_for("HWBVH-C", ram_pairs=r))["cycles"] for r in (1, 2, 4)]
    assert all(a >= b for a, b in zip(ram, ram[1:])), ram
    sb = [simulate(tree, params_for("HWBVH-C", subtree_builders=k))["cycles"] for k in (1, 2, 4)]
    assert all(a >= b for a, b in zip(sb, sb[1:])), sb
    c = simulate(tree, PRESETS["HWBVH-C"])
    hp = simulate(tree, PRESETS["HWBVH-HP"])
    assert hp["seconds"] < c["seconds"] / 2


def test_parameters_are_checked():
    with pytest.raises(InputError, match="power of two"):
        params_for("HWBVH-C", w=3)
    with pytest.raises(InputError, match="preset"):
        params_for("HWBVH-X")


def test_design_space_trends(tmp_path):
    tris = bumpy_sphere(40_000)
    r = sweep(tris, tmp_path, leaf_sizes=(4, 64), n_subtrees=2)
    get = {(x["leaf_size"], x["w"], x["tsize"]): x["speedup"] for x in r["rows"]}
    # leaf size 4: threads dominate; w alone barely helps
    assert get[(4, 2, 16)] > get[(4, 16, 2)]
    assert get[(4, 16, 2)] < 1.6
    # leaf size 64: width dominates; threads alone barely help
    assert get[(64, 16, 2)] > get[(64, 2, 16)]
    assert get[(64, 2, 16)] < 1.3
    assert (tmp_path / "sweep.csv").exists() and (tmp_path / "fig4_2_speedup.png").exists()


def test_cli_simulate_json(tmp_path):
    import trimesh
    tris = random_soup(3000)
    p = tmp_path / "m.ply"
    trimesh.Trimesh(tris.reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3), process=False).export(p)
    r = subprocess.run([sys.executable, "-m", "hwrt.cli", "simulate", str(p), "--preset", "HWBVH-HP", "--json"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    for k in ("cycles", "clock_hz", "seconds", "traffic_bytes", "footprint_bytes", "energy_joules", "sah_cost"):
        assert k in res
    assert set(res["traffic_bytes"]) == {"aabb", "upper_sort", "nodes", "indices"}
    assert res["clock_hz"] == 500e6
