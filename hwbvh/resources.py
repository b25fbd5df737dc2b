"""Resources, area and active power of any instantiation (thesis 4.3.4, Tables 4.5-4.10).

Tables 4.5-4.7 list, per unit, the floating-point cores, the register space and the number of
units an instantiation uses; Table 4.8 sums them. Here the same tabulation is a function of the
parameters:

* a subtree builder has w partitioning units, w binning-unit groups (three binners each),
  2 * Tsize SAH calculators (each fed by w groups) and one tree output; its primitive buffers are
  2 * w * Psize records of 27 bytes in SRAM (432 KB at 8,192 primitives);
* the upper builder has one partitioning unit and one binning group per RAM pair and one SAH
  calculator pair (fed by one group per RAM pair);
* registers scale with what the text says they hold: thread contexts (Tsize per partitioning
  unit), bin records (per bin, per axis, per group), the cost evaluators' bin streams and the
  index output FIFOs (w * Tsize of Psize entries).

Gates, area and power then follow the thesis' InCyte estimate: cores, register and SRAM bits in
gates, 20% of the core left to miscellaneous logic, one area per gate, and a power per gate and
hertz that grows with the clock, fitted on the two presets (``hwbvh.calibration.fit_cost_model``).
For HWBVH-C and HWBVH-HP the tabulation reproduces Table 4.8 and Table 4.9's bit counts exactly,
and the power Table 4.10's.
"""
from . import config

UNITS = ("partitioning_unit", "binning_unit", "sah_calculator", "tree_output")


def _cores(unit, groups=0, upper_pairs=0):
    """Floating-point cores of one ``unit``; ``groups`` binning groups feed an SAH calculator;
    ``upper_pairs`` > 0 for an upper-builder partitioning unit."""
    out = dict.fromkeys(config.FP_TYPES, 0)
    out.update(config.FP_CORES_PER_UNIT[unit])
    if unit == "sah_calculator":
        out["cmp"] = config.SAH_CMP_PER_GROUP * groups
    if unit == "partitioning_unit" and upper_pairs:
        out["cmp"] = config.UPPER_PU_CMP_PER_RAM_PAIR * upper_pairs
    return out


def _sah_registers(bins, groups, other):
    """One SAH calculator: a bin collector per group (three axes of bin records), the three cost
    evaluators' bin-stream LIFO and the FIFO and LIFO of their float32 terms, and the rest."""
    collectors = groups * 3 * bins * config.BIN_RECORD_BYTES
    evaluators = 3 * bins * (config.BIN_RECORD_BYTES + 2 * config.SAH_TERM_BYTES)
    return collectors + evaluators + other


def _builder(counts, cores, registers, sram):
    units = {u: {"count": counts[u], "fp_cores": cores[u], "register_bytes": registers[u]}
             for u in UNITS}
    return {"units": units,
            "fp_cores": {t: sum(counts[u] * cores[u][t] for u in UNITS) for t in config.FP_TYPES},
            "register_bytes": sum(counts[u] * registers[u] for u in UNITS),
            "sram_bytes": sram}


def subtree_builder(p):
    """Resources of one subtree builder of instantiation ``p`` (Table 4.5 for the presets)."""
    counts = {"partitioning_unit": p.w, "binning_unit": p.w, "sah_calculator": 2 * p.tsize,
              "tree_output": 1}
    cores = {"partitioning_unit": _cores("partitioning_unit"), "binning_unit": _cores("binning_unit"),
             "sah_calculator": _cores("sah_calculator", groups=p.w), "tree_output": _cores("tree_output")}
    registers = {
        "partitioning_unit": config.PARTITIONING_UNIT_REG_BYTES + p.tsize * config.THREAD_CONTEXT_BYTES,
        "binning_unit": config.BINNING_GROUP_REG_BYTES,
        "sah_calculator": _sah_registers(p.bins, p.w, config.SAH_CALC_OTHER_REG_BYTES),
        "tree_output": p.w * p.tsize * p.psize * config.INDEX_FIFO_ENTRY_BYTES,
    }
    sram = 2 * p.w * p.psize * config.PRIMITIVE_RECORD_BYTES     # the primitive buffer pairs
    return _builder(counts, cores, registers, sram)


def upper_builder(p):
    """Resources of the upper builder of instantiation ``p`` (Tables 4.6/4.7 for the presets)."""
    r = p.ram_pairs
    counts = {"partitioning_unit": r, "binning_unit": r, "sah_calculator": 2, "tree_output": 1}
    cores = {"partitioning_unit": _cores("partitioning_unit", upper_pairs=r),
             "binning_unit": _cores("binning_unit"),
             "sah_calculator": _cores("sah_calculator", groups=r), "tree_output": _cores("tree_output")}
    registers = {
        "partitioning_unit": config.UPPER_PU_REG_BYTES,
        "binning_unit": config.BINNING_GROUP_REG_BYTES,
        "sah_calculator": _sah_registers(p.bins, r, config.UPPER_SAH_CALC_OTHER_REG_BYTES),
        "tree_output": config.UPPER_TREE_OUTPUT_REG_BYTES,
    }
    return _builder(counts, cores, registers, 0)


def _checked(p):
    """``p`` within the hardware's ranges (a preset's name stands for the preset): the tables
    below would otherwise turn a negative or zero knob into a negative area, or fail deep inside."""
    from .cycle_model import as_params
    return as_params(p, name="p")


def resources(p):
    """Table 4.5-4.8 for instantiation ``p``: the subtree builder (one of them), the upper
    builder, and the system totals (``subtree_builders`` subtree builders + the upper builder)."""
    p = _checked(p)
    sub = subtree_builder(p)
    up = upper_builder(p)
    k = p.subtree_builders
    total = {"fp_cores": {t: k * sub["fp_cores"][t] + up["fp_cores"][t] for t in config.FP_TYPES},
             "register_bytes": k * sub["register_bytes"] + up["register_bytes"],
             "sram_bytes": k * sub["sram_bytes"]}
    return {"subtree_builder": sub, "subtree_builders": k, "upper_builder": up, "total": total}


def gates(total, gates_per_core=None, gates_per_bit=None):
    """Equivalent gates of a system total: cores, register and SRAM bits, then miscellaneous
    logic as ``MISC_LOGIC_SHARE`` of the whole core."""
    gc = config.GATES_PER_FP_CORE if gates_per_core is None else gates_per_core
    gb = config.GATES_PER_STORAGE_BIT if gates_per_bit is None else gates_per_bit
    cores = total["fp_cores"]
    fp = config.COMPARATOR_GATES * cores["cmp"] + gc * sum(v for t, v in cores.items() if t != "cmp")
    storage = gb * 8 * (total["register_bytes"] + total["sram_bytes"])
    core = (fp + storage) / (1.0 - config.MISC_LOGIC_SHARE)
    return {"fp_cores": fp, "storage": storage, "misc": core - fp - storage, "total": core}


def cost(p):
    """Area (mm^2, 90 nm) and active power (W) of instantiation ``p`` at its clock, with the
    gates and the system's resource totals they come from."""
    p = _checked(p)
    res = resources(p)
    g = gates(res["total"])
    return {"area_mm2": config.AREA_MM2_PER_GATE * g["total"],
            "active_power_w": active_power_w(g["total"], p.clock_mhz),
            "gates": g, "resources": res["total"]}


def active_power_w(total_gates, clock_mhz, per_gate_hz=None, exponent=None):
    """Active power (W) of ``total_gates`` equivalent gates switching at ``clock_mhz``: a price
    per gate and hertz at the reference clock, growing with the clock (config's reasons)."""
    k = config.ACTIVE_W_PER_GATE_HZ if per_gate_hz is None else per_gate_hz
    e = config.POWER_CLOCK_EXPONENT if exponent is None else exponent
    return k * total_gates * clock_mhz * 1e6 * (clock_mhz / config.POWER_REFERENCE_MHZ) ** e
