"""The resource, area and power model against thesis Tables 4.5-4.10, its scaling with every
knob, and the energy that ``simulate`` derives from it."""
from dataclasses import replace

import numpy as np
import pytest

from hwbvh import config
from hwbvh.builder import build_canonical
from hwbvh.cycle_model import PRESETS, check_params, params_for, simulate
from hwbvh.errors import ParameterError
from hwbvh.primitives import primitive_boxes
from hwbvh.resources import cost, resources
from scenes.meshes import random_soup

C, HP = PRESETS["HWBVH-C"], PRESETS["HWBVH-HP"]
KIB = 1024

# Table 4.8 (system totals) and Table 4.9 (the bits given to InCyte)
TABLE_4_8 = {
    "HWBVH-C": {"add": 182, "sub": 222, "mul": 236, "div": 20, "cmp": 2382, "fxd_flt": 54, "flt_fxd": 20},
    "HWBVH-HP": {"add": 346, "sub": 426, "mul": 448, "div": 40, "cmp": 4776, "fxd_flt": 102, "flt_fxd": 40},
}
TABLE_4_8_KB = {"HWBVH-C": (587, 432), "HWBVH-HP": (1161, 864)}
TABLE_4_9_BITS = {"HWBVH-C": (3_538_944, 4_808_704), "HWBVH-HP": (7_077_888, 9_510_912)}


@pytest.mark.parametrize("name", ["HWBVH-C", "HWBVH-HP"])
def test_system_totals_are_table_4_8_and_the_bits_table_4_9(name):
    total = resources(PRESETS[name])["total"]
    assert total["fp_cores"] == TABLE_4_8[name]
    reg_kb, sram_kb = TABLE_4_8_KB[name]
    assert total["register_bytes"] == reg_kb * KIB and total["sram_bytes"] == sram_kb * KIB
    sram_bits, rf_bits = TABLE_4_9_BITS[name]
    assert 8 * total["sram_bytes"] == sram_bits and 8 * total["register_bytes"] == rf_bits


def test_per_unit_columns_of_tables_4_5_to_4_7():
    sub = resources(C)["subtree_builder"]["units"]
    # Table 4.5: units used, cores per unit, register KB per unit
    assert {u: v["count"] for u, v in sub.items()} == {"partitioning_unit": 4, "binning_unit": 4,
                                                       "sah_calculator": 16, "tree_output": 1}
    assert sub["sah_calculator"]["fp_cores"] == {"add": 9, "sub": 9, "mul": 12, "div": 0, "cmp": 144,
                                                 "fxd_flt": 3, "flt_fxd": 0}
    assert [round(sub[u]["register_bytes"] / KIB) for u in sub] == [2, 4, 9, 256]
    assert resources(C)["subtree_builder"]["fp_cores"] == {"add": 160, "sub": 192, "mul": 208, "div": 16,
                                                           "cmp": 2304, "fxd_flt": 48, "flt_fxd": 16}
    # Tables 4.6 / 4.7: the upper builder at one and two RAM pairs
    for p, cmp_pu, cmp_sah, sah_kb, total in ((C, 6, 36, 6, (22, 30, 28, 4, 78, 6, 4)),
                                              (HP, 12, 72, 7, (26, 42, 32, 8, 168, 6, 8))):
        up = resources(p)["upper_builder"]
        assert up["units"]["partitioning_unit"]["fp_cores"]["cmp"] == cmp_pu
        assert up["units"]["sah_calculator"]["fp_cores"]["cmp"] == cmp_sah
        assert round(up["units"]["sah_calculator"]["register_bytes"] / KIB) == sah_kb
        assert round(up["units"]["binning_unit"]["register_bytes"] / KIB) == 4
        assert round(up["units"]["tree_output"]["register_bytes"] / KIB) == 4
        assert tuple(up["fp_cores"].values()) == total


def test_builder_totals_round_as_the_tables_do():
    # the tables print 422 + 164 = 587: the exact split is 422.5 + 164.5 (rounded half to even)
    sub = resources(C)["subtree_builder"]["register_bytes"] / KIB
    up_c = resources(C)["upper_builder"]["register_bytes"] / KIB
    up_hp = resources(HP)["upper_builder"]["register_bytes"] / KIB
    assert (sub, up_c, up_hp) == (422.5, 164.5, 316.0)
    assert (round(sub), round(up_c), round(up_hp)) == (422, 164, 316)
    # 432 KB of primitive buffers per subtree builder at 8,192 primitives
    assert resources(C)["subtree_builder"]["sram_bytes"] == 432 * KIB


def test_fit_reproduces_the_shipped_constants_and_table_4_10_within_its_error():
    from hwbvh.calibration import fit_cost_model
    f = fit_cost_model()
    assert f["gates_per_fp_core"] == pytest.approx(config.GATES_PER_FP_CORE, rel=1e-4)
    assert f["gates_per_storage_bit"] == pytest.approx(config.GATES_PER_STORAGE_BIT, rel=1e-4)
    assert f["area_mm2_per_gate"] == pytest.approx(config.AREA_MM2_PER_GATE, rel=1e-4)
    assert f["active_w_per_gate_hz"] == pytest.approx(config.ACTIVE_W_PER_GATE_HZ, rel=1e-4)
    assert f["power_clock_exponent"] == pytest.approx(config.POWER_CLOCK_EXPONENT, rel=1e-4)
    # the fitted weights are physical: a 32-bit FP core of a few thousand gates, under a gate per bit
    assert 2000 < f["gates_per_fp_core"] < 20000 and 0.1 < f["gates_per_storage_bit"] < 2
    for name, p in PRESETS.items():
        c = cost(p)
        assert c["gates"]["total"] == pytest.approx(config.THESIS_TOTAL_GATES[name], rel=1e-5)
        assert c["gates"]["misc"] == pytest.approx(0.2 * c["gates"]["total"])
        assert c["area_mm2"] == pytest.approx(config.THESIS_AREA_MM2[name], rel=0.018)
        # SPEC 6: a preset's energy is Table 4.10's active power x its time
        assert c["active_power_w"] == pytest.approx(config.THESIS_ACTIVE_POWER_W[name], rel=1e-4)
        assert abs(f["area_ratio"][name] - 1) < 0.018 and abs(f["power_ratio"][name] - 1) < 1e-9


@pytest.mark.parametrize("knob,lo,hi", [("w", 2, 16), ("tsize", 2, 32), ("psize", 1024, 4096),
                                        ("subtree_builders", 1, 4), ("ram_pairs", 1, 4), ("bins", 4, 16)])
def test_every_hardware_knob_costs_area(knob, lo, hi):
    a, b = cost(replace(C, **{knob: lo})), cost(replace(C, **{knob: hi}))
    assert b["area_mm2"] > a["area_mm2"]
    assert b["active_power_w"] / a["active_power_w"] == pytest.approx(b["area_mm2"] / a["area_mm2"])


def test_clock_costs_power_not_area_and_leaf_size_costs_nothing():
    a, b = cost(C), cost(replace(C, clock_mhz=500.0))
    # a little faster than in proportion: a faster design switches stronger cells (config)
    assert b["area_mm2"] == a["area_mm2"] and b["active_power_w"] == pytest.approx(
        2 * 2 ** config.POWER_CLOCK_EXPONENT * a["active_power_w"])
    assert 0 < config.POWER_CLOCK_EXPONENT < 0.5
    assert cost(replace(C, leaf_size=32)) == a


def test_units_scale_with_the_parameters():
    p = replace(C, w=8, tsize=16, psize=1024, bins=8, ram_pairs=3, subtree_builders=2)
    r = resources(p)
    sub, up = r["subtree_builder"], r["upper_builder"]
    assert sub["units"]["sah_calculator"]["count"] == 32
    assert sub["units"]["sah_calculator"]["fp_cores"]["cmp"] == 36 * 8
    assert sub["units"]["tree_output"]["register_bytes"] == 8 * 16 * 1024 * 4
    assert sub["sram_bytes"] == 2 * 8 * 1024 * 27
    assert up["units"]["partitioning_unit"]["count"] == 3
    assert up["units"]["partitioning_unit"]["fp_cores"]["cmp"] == 18
    assert r["total"]["sram_bytes"] == 2 * sub["sram_bytes"]
    # bin records: 3 axes x 27 bytes per bin per feeding group, plus the evaluators' streams
    d = (resources(replace(p, bins=16))["subtree_builder"]["units"]["sah_calculator"]["register_bytes"]
         - sub["units"]["sah_calculator"]["register_bytes"])
    assert d == 8 * (8 * 3 * 27 + 3 * (27 + 8))


def test_simulate_derives_area_power_and_energy_for_any_configuration():
    tree = build_canonical(primitive_boxes(random_soup(4000, seed=5)))
    for p in (C, HP, params_for("HWBVH-C", w=16, tsize=32, psize=512, subtree_builders=4)):
        r = simulate(tree, p)
        c = cost(p)
        assert r["area_mm2"] == c["area_mm2"] and r["active_power_w"] == c["active_power_w"]
        assert r["energy_joules"] == r["seconds"] * c["active_power_w"]
        assert r["resources"]["register_bytes"] == c["resources"]["register_bytes"]
    custom = simulate(tree, params_for("HWBVH-C", w=16, tsize=32, psize=512, subtree_builders=4))
    assert custom["active_power_w"] > cost(C)["active_power_w"] * 1.5


@pytest.mark.parametrize("knob,value,match", [
    ("bins", 17, "bins"), ("bins", 1, "bins"), ("w", 0, "w"), ("w", 3, "power of two"),
    ("tsize", 128, "tsize"), ("clock_mhz", 0.0, "clock_mhz"), ("clock_mhz", float("nan"), "clock_mhz"),
    ("psize", 1 << 23, "24-bit"), ("leaf_size", 0, "leaf_size"), ("ram_pairs", 2.0, "ram_pairs"),
    ("control_latency", -1, "control_latency")])
def test_out_of_range_knobs_name_the_parameter(knob, value, match):
    with pytest.raises(ParameterError, match=match) as e:
        check_params(replace(C, **{knob: value}))
    assert e.value.parameter == ("psize" if knob == "psize" else knob)
    with pytest.raises(ParameterError):
        params_for("HWBVH-C", **{knob: value})


def test_presets_are_within_range():
    for p in PRESETS.values():
        assert check_params(p) == p          # as given: already Python numbers
    assert np.isfinite(cost(C)["area_mm2"])
