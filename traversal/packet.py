"""Packet traversal: P coherent rays (``traversal.config.PACKET_RAYS``, 16) walk the raw tree
together (Wald et al. 2001).

The units are the same as in ``traverse``: every lane's box test and Moller-Trumbore test
runs the datapath the single-ray path runs (``aabb_unit.slab_test``,
``triangle_unit.mt_datapath``), so each lane's answer is bit for bit the single-ray answer (the
closest hit is unique: exact-t ties go to the lower primitive index). What changes is the loop
order: a node is fetched once for the packet and its boxes and triangles are tested against all
P lanes in one branch-free loop, which LLVM's loop vectoriser turns into SIMD code (AVX2 or
AVX-512, as the CPU offers). Scalar Numba has no other route to SIMD.

A packet visits the union of its lanes' nodes, so it pays only when the rays are coherent.
``traverse._trace_range`` sends each run of consecutive groups of P rays that each share a
direction octant (primary rays of a camera, shadow rays toward a light, a mirror's reflections)
here in one call; any other group goes ray by ray.
"""
import math

import numpy as np
from numba import njit

from hwbvh.config import LEAF_FLAG
from hwbvh.format import BOX_MAX, WORD_A, WORD_B, WORD_BOX, WORD_FLAGS, WORDS_PER_NODE
from .aabb_unit import slab_test
from .config import PACKET_RAYS as P
from .rawtree import read_index
from .triangle_unit import (TRI_E1, TRI_E2, TRI_NORMS, TRI_SCALE, TRI_V0, TRI_WORDS, mt_datapath,
                            ray_band_terms, takes_hit)


# Lane state lives in flat scratch arrays, one row of P per quantity at a constant offset, so
# LLVM can prove that the rows do not overlap and vectorise the lane loops (with a dozen
# separate arrays it would need more run-time alias checks than it allows, and gives up).
# DD and RS hold the ray's side of the parallel band (``triangle_unit.ray_band_terms``).
OX, OY, OZ, DX, DY, DZ, IX, IY, IZ, DD, RS, TMIN, BEST, BU, BV = [r * P for r in range(15)]
NF = 15 * P           # floats per packet scratch
PRIM = 0
NI = P            # int32s per packet scratch
# Lane masks are bytes, read back 8 lanes at a time through a uint64 view of the same bytes:
# "does any lane hit" is then two loads, not a reduction loop (which Numba's integer typing
# would widen to int64 and LLVM would leave scalar).
ALIVE, MASK = 0, P    # M[ALIVE + k]: lane k still traced; M[MASK + k]: its box-test bits
NM = 2 * P            # bytes per packet scratch
NW = P // 8           # uint64 words per mask row
LANES_L = 0x0101010101010101      # bit 0 of every byte: hits the (left) box
LANES_R = 0x0202020202020202      # bit 1: hits the right box


@njit(cache=True, error_model="numpy", inline="always")
def _slab(F, k, nx_, ny_, nz_, fx_, fy_, fz_, widen):
    """Lane k against a box given by its near planes (nx_, ny_, nz_) and far planes for the
    packet's octant, through the AABB unit's ``slab_test``. Returns the hit flag. (The
    comparator on the sign of 1/d picks the same planes for every lane, since the lanes share
    the sign bits of d.)"""
    return slab_test(nx_, ny_, nz_, fx_, fy_, fz_, F[OX + k], F[OY + k], F[OZ + k],
                     F[IX + k], F[IY + k], F[IZ + k], F[TMIN + k], F[BEST + k], widen)[0]


@njit(cache=True, error_model="numpy", inline="always")
def _planes(f, b, kx, ky, kz):
    """Near and far planes of box f[b:b + 6] (min xyz, max xyz) for near-plane offsets
    (kx, ky, kz) (0 or BOX_MAX)."""
    return (f[b + kx], f[b + 1 + ky], f[b + 2 + kz],
            f[b + BOX_MAX - kx], f[b + 1 + BOX_MAX - ky], f[b + 2 + BOX_MAX - kz])


@njit(cache=True, error_model="numpy", inline="always")
def row_bits(M64, row):
    """OR of the uint64 words of the lane row at byte offset ``row`` (``ALIVE``: non-zero while
    some lane is traced; ``MASK``: bit 0 / bit 1 of some byte set = some lane hits)."""
    first = row // 8
    w = M64[first]
    for q in range(1, NW):
        w |= M64[first + q]
    return w


@njit(cache=True, error_model="numpy", inline="always")
def _children(f, bl, br, kx, ky, kz, F, M, M64, widen):
    """Both child boxes against every live lane: M[MASK + k] = (hits left) | (hits right) << 1.
    Returns the OR of the mask words."""
    lnx, lny, lnz, lfx, lfy, lfz = _planes(f, bl, kx, ky, kz)
    rnx, rny, rnz, rfx, rfy, rfz = _planes(f, br, kx, ky, kz)
    for k in range(P):
        hl = _slab(F, k, lnx, lny, lnz, lfx, lfy, lfz, widen)
        hr = _slab(F, k, rnx, rny, rnz, rfx, rfy, rfz, widen)
        live = M[ALIVE + k] != 0
        M[MASK + k] = np.uint8(live & hl) | (np.uint8(live & hr) << 1)
    return row_bits(M64, MASK)


@njit(cache=True, error_model="numpy", inline="always")
def _box(f, b, kx, ky, kz, F, M, M64, widen):
    """One box against every live lane: M[MASK + k] = 1 where lane k hits. Returns the OR of
    the mask words (non-zero when some lane hits)."""
    nx, ny, nz, fx, fy, fz = _planes(f, b, kx, ky, kz)
    for k in range(P):
        h = _slab(F, k, nx, ny, nz, fx, fy, fz, widen)
        M[MASK + k] = np.uint8((M[ALIVE + k] != 0) & h)
    return row_bits(M64, MASK)


@njit(cache=True, error_model="numpy", inline="always")
def _mt(F, k, v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z, band, tscale, lo, hi, tmax, one):
    """Lane k against one triangle through the Moller-Trumbore unit's ``mt_datapath``, up to
    ``tmax`` (the lane's F[BEST + k], read by the caller). Returns (valid, t, u, v)."""
    return mt_datapath(v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z, band, tscale,
                       F[OX + k], F[OY + k], F[OZ + k], F[DX + k], F[DY + k], F[DZ + k],
                       F[DD + k], F[RS + k], lo, hi, F[TMIN + k], tmax, one)


@njit(cache=True, error_model="numpy", inline="always")
def _triangle(tris, row, j, F, I, M, bit, eps2, one, edge, anyhit):
    """Triangle j (row ``row`` of ``tris``) against the live lanes with bit ``bit`` set in
    M[MASK]. Updates their closest hits; for any-hit queries a lane that hits retires
    (M[ALIVE] = 0).

    Every lane's row is written whole, the kept value included. Written as
    ``F[BEST + k] = t if take else F[BEST + k]``, LLVM drops the store of an unchanged value
    and vectorises what is left as masked stores (``vmaskmovps``), which AMD's Zen cores run as
    long microcode sequences; so the old values are read first and kept through arithmetic it
    cannot fold (``best - zero`` with a zero known only at run time; in any-hit queries
    ``max(p, -1)``, as a live lane has no blocker yet, p = -1). The lane tests stay byte-wide:
    ``(M[MASK + k] >> bit) & 1`` widens every lane to 64 bits. docs/design.md has the
    measurement ("No masked stores in the lanes")."""
    b = TRI_WORDS * row
    v0x = tris[b + TRI_V0]; v0y = tris[b + TRI_V0 + 1]; v0z = tris[b + TRI_V0 + 2]
    e1x = tris[b + TRI_E1]; e1y = tris[b + TRI_E1 + 1]; e1z = tris[b + TRI_E1 + 2]
    e2x = tris[b + TRI_E2]; e2y = tris[b + TRI_E2 + 1]; e2z = tris[b + TRI_E2 + 2]
    band = eps2 * tris[b + TRI_NORMS]
    tscale = tris[b + TRI_SCALE]
    lo = -edge
    hi = one + edge
    zero = one - one
    sel = np.uint8(1 << bit)
    jj = np.int32(j)
    if anyhit:
        for k in range(P):
            ok, t, u, v = _mt(F, k, v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z, band, tscale,
                              lo, hi, F[BEST + k], one)
            a = M[ALIVE + k]
            p = I[PRIM + k]
            take = ok & ((M[MASK + k] & sel) != 0) & (a != 0)
            I[PRIM + k] = max(p, jj if take else np.int32(-1))
            M[ALIVE + k] = a & np.uint8(not take)
        return
    for k in range(P):
        best = F[BEST + k]
        ok, t, u, v = _mt(F, k, v0x, v0y, v0z, e1x, e1y, e1z, e2x, e2y, e2z, band, tscale,
                          lo, hi, best, one)
        p = I[PRIM + k]
        bu = F[BU + k]
        bv = F[BV + k]
        take = takes_hit(ok & ((M[MASK + k] & sel) != 0) & (M[ALIVE + k] != 0), t, jj, best, p)
        F[BEST + k] = t if take else best - zero
        I[PRIM + k] = jj if take else p
        F[BU + k] = u if take else bu
        F[BV + k] = v if take else bv


@njit(cache=True, error_model="numpy", _nrt=False)
def coherent(D, lo, hi):
    """True when rays [lo, hi) all lie in one direction octant: the sign bits of d agree, so
    1/d has the same signs (d = -0 gives 1/d = -inf: -0 counts as negative)."""
    sx = math.copysign(1.0, D[lo, 0])
    sy = math.copysign(1.0, D[lo, 1])
    sz = math.copysign(1.0, D[lo, 2])
    for i in range(lo + 1, hi):
        if math.copysign(1.0, D[i, 0]) != sx or math.copysign(1.0, D[i, 1]) != sy or \
                math.copysign(1.0, D[i, 2]) != sz:
            return False
    return True


@njit(cache=True, inline="always")
def octant(dx, dy, dz):
    """The direction octant 0..7 of (dx, dy, dz) from its sign bits (-0 counts as negative):
    rays with the same octant may share a packet (``coherent``). A float64 direction and its
    float32 copy have the same octant."""
    return np.int64(np.signbit(dx)) | (np.int64(np.signbit(dy)) << 1) | \
        (np.int64(np.signbit(dz)) << 2)


@njit(cache=True, error_model="numpy", inline="always")
def coherent_packet(Df, lo):
    """``coherent(D, lo, lo + P)`` on the directions seen flat (3n,), as the traversal asks it
    once per packet: every component of every ray against the previous ray's, without a
    branch, over a view of exactly 3P words indexed from 0, so that the loop runs in SIMD
    lanes (a packet that misses the scene costs 66 ns against 81 with an early-exit loop; with
    a length known only at run time, or 2D indexing, it stays scalar)."""
    s = Df[3 * lo:3 * lo + 3 * P]
    differ = False
    for k in range(3, 3 * P):
        differ |= math.copysign(1.0, s[k]) != math.copysign(1.0, s[k - 3])
    return not differ


def packet_rays(dirs):
    """Which rays of a batch ``dirs`` (n, 3) the traversal traces in packets (the rule of
    ``traverse._trace_range``): those in full groups of P consecutive rays, aligned to the
    batch's start, that pass ``coherent``. NumPy, for reports; the kernels decide for
    themselves."""
    dirs = np.asarray(dirs)
    n = len(dirs)
    full = n // P * P
    octant = np.signbit(dirs[:full]) @ np.array([1, 2, 4])     # -0 counts as negative
    groups = octant.reshape(-1, P)
    in_packets = np.zeros(n, bool)
    in_packets[:full] = np.repeat((groups == groups[:, :1]).all(axis=1), P)
    return in_packets


@njit(cache=True, error_model="numpy", inline="always")
def _left_first(f, bl, br, negx, negy, negz):
    """Front-to-back order for a packet whose rays share an octant: along the axis on which the
    two child boxes' centres lie farthest apart, the child whose centre comes first in the
    packet's direction along that axis. ``bl``/``br``: the boxes' first words in ``f``."""
    m = BOX_MAX
    cx = (f[br] + f[br + m]) - (f[bl] + f[bl + m])      # twice the centre offset, right - left
    cy = (f[br + 1] + f[br + 1 + m]) - (f[bl + 1] + f[bl + 1 + m])
    cz = (f[br + 2] + f[br + 2 + m]) - (f[bl + 2] + f[bl + 2 + m])
    ax = abs(cx)
    ay = abs(cy)
    az = abs(cz)
    if ax >= ay and ax >= az:
        return (cx >= 0) != negx
    if ay >= az:
        return (cy >= 0) != negy
    return (cz >= 0) != negz


@njit(cache=True, error_model="numpy", inline="always")
def _lane_setup(F, I, M, k, ok, ox, oy, oz, dx, dy, dz, a, b, zero, one):
    """Lane k's ray state; a dead lane (ok False) gets harmless values and is never live."""
    dx = dx if ok else one
    dy = dy if ok else one
    dz = dz if ok else one
    F[OX + k] = ox if ok else zero
    F[OY + k] = oy if ok else zero
    F[OZ + k] = oz if ok else zero
    F[DX + k] = dx
    F[DY + k] = dy
    F[DZ + k] = dz
    F[TMIN + k] = a if ok else zero
    F[BEST + k] = b if ok else zero
    ix = one / dx                               # the divider, once per ray
    iy = one / dy
    iz = one / dz
    F[IX + k] = ix
    F[IY + k] = iy
    F[IZ + k] = iz
    rs, dd = ray_band_terms(dx, dy, dz)
    F[DD + k] = dd
    F[RS + k] = rs
    M[ALIVE + k] = np.uint8(ok)
    I[PRIM + k] = -1
    F[BU + k] = zero
    F[BV + k] = zero


@njit(cache=True, error_model="numpy", inline="always")
def load_lane(F, I, M, k, Os, Ds, As, Bs, zero, one):
    """Lane k's ray from the packet's views (origins and directions flat, bounds), checked as
    the unit's ``rawtree._ray_ok`` but without branches (x - x == 0 exactly when x is finite),
    so that the lane loop runs in SIMD; a dead lane is set up harmless (``_lane_setup``).
    Returns whether the unit accepts the ray."""
    ox = Os[3 * k]; oy = Os[3 * k + 1]; oz = Os[3 * k + 2]
    dx = Ds[3 * k]; dy = Ds[3 * k + 1]; dz = Ds[3 * k + 2]
    a = As[k]
    b = Bs[k]
    ok = ((ox - ox) == 0) & ((oy - oy) == 0) & ((oz - oz) == 0) & ((dx - dx) == 0) \
        & ((dy - dy) == 0) & ((dz - dz) == 0) & ((dx != 0) | (dy != 0) | (dz != 0)) \
        & (a <= b)
    _lane_setup(F, I, M, k, ok, ox, oy, oz, dx, dy, dz, a, b, zero, one)
    return ok


@njit(cache=True, error_model="numpy", _nrt=False)
def trace_packets(u, f, ib, tris, O, D, tmin_in, tmax_in, eps2, one, widen, edge, lo, hi, anyhit,
                  stack, F, I, M, M64, out_prim, out_t, out_u, out_v, counters):
    """Rays [lo, hi) (a multiple of P, each group of P sharing a direction octant) as packets,
    one after the other; ``O``/``D`` are the (n, 3) origins and directions seen flat (3n,).
    Scratch: ``F`` (NF,) of the working float type, ``I`` (NI,) int32, ``M`` (NM,) uint8 and
    ``M64`` its uint64 view. Writes out_prim (and out_t/u/v when they are not empty). Returns
    the rays whose stack would overflow (a corrupted tree), else 0.

    One call per run of packets, not per packet: a call passes some 130 words of array
    descriptors and re-checks that the scratch rows do not overlap the rays, which cost about
    as much as setting up the packet's 16 lanes."""
    over = 0
    for a in range(lo, hi, P):
        over += _packet(u, f, ib, tris, O, D, tmin_in, tmax_in, eps2, one, widen, edge, a,
                        a + P, anyhit, stack, F, I, M, M64, out_prim, out_t, out_u, out_v,
                        counters) * P
    return over


@njit(cache=True, error_model="numpy", inline="always")
def _packet(u, f, ib, tris, O, D, tmin_in, tmax_in, eps2, one, widen, edge, lo, hi, anyhit,
            stack, F, I, M, M64, out_prim, out_t, out_u, out_v, counters):
    """Rays [lo, hi) (exactly P, sharing a direction octant) as one packet (see
    ``trace_packets``). Returns 1 if the stack would overflow, else 0."""
    zero = one - one
    # a full packet: branch-free, so the loads, the checks and the dividers run in SIMD
    # (indices from 0 on views: with lo + k, LLVM cannot bound the addresses)
    Os = O[3 * lo:3 * lo + 3 * P]
    Ds = D[3 * lo:3 * lo + 3 * P]
    As = tmin_in[lo:lo + P]
    Bs = tmax_in[lo:lo + P]
    for k in range(P):
        load_lane(F, I, M, k, Os, Ds, As, Bs, zero, one)
    nlive = 1 if row_bits(M64, ALIVE) != 0 else 0
    # the packet's octant, shared by its rays (``coherent``): the comparator on the sign of
    # 1/d, once for the packet
    negx = math.copysign(1.0, D[3 * lo]) < 0
    negy = math.copysign(1.0, D[3 * lo + 1]) < 0
    negz = math.copysign(1.0, D[3 * lo + 2]) < 0
    kx = BOX_MAX if negx else 0
    ky = BOX_MAX if negy else 0
    kz = BOX_MAX if negz else 0
    over = 0
    visited = 0                 # work as the packet does it: every lane takes part in every
    tested = 0                  # node visit and triangle test of the packet
    if nlive > 0 and _box(f, WORD_BOX, kx, ky, kz, F, M, M64, widen) != 0:
        node = 0
        bit = 0           # which bit of M[MASK] holds the current node's lanes; -1: not known
        sp = 0
        while True:
            visited += 1
            base = WORDS_PER_NODE * node
            if u[base + WORD_FLAGS] & LEAF_FLAG:
                # leaf: the lanes whose ray reaches its box test its primitives
                if bit < 0:
                    bit = 0 if _box(f, base + WORD_BOX, kx, ky, kz, F, M, M64, widen) != 0 else -1
                if bit >= 0:
                    first = np.int64(u[base + WORD_A])
                    tested += np.int64(u[base + WORD_B])
                    for p in range(first, first + np.int64(u[base + WORD_B])):
                        _triangle(tris, p, read_index(ib, p), F, I, M, bit, eps2, one, edge,
                                  anyhit)
                    if anyhit and row_bits(M64, ALIVE) == 0:
                        break                   # every lane has found a blocker
                node = -1
            else:
                l = np.int64(u[base + WORD_A])
                r = np.int64(u[base + WORD_B])
                bl = WORDS_PER_NODE * l + WORD_BOX
                br = WORDS_PER_NODE * r + WORD_BOX
                bits = _children(f, bl, br, kx, ky, kz, F, M, M64, widen)
                hl = (bits & LANES_L) != 0
                hr = (bits & LANES_R) != 0
                if hl and hr:
                    if sp >= stack.shape[0]:
                        over = 1
                        break
                    if _left_first(f, bl, br, negx, negy, negz):
                        stack[sp] = r
                        node = l
                        bit = 0
                    else:
                        stack[sp] = l
                        node = r
                        bit = 1
                    sp += 1
                elif hl:
                    node = l
                    bit = 0
                elif hr:
                    node = r
                    bit = 1
                else:
                    node = -1
            if node < 0:
                if sp == 0:
                    break
                sp -= 1
                node = stack[sp]
                bit = -1                        # a popped node's lanes are re-tested
    hits_out = out_t.shape[0] > 0
    if over:
        for k in range(P):
            I[PRIM + k] = -1
    n = hi - lo
    outp = out_prim[lo:hi]                      # views indexed from 0 (see the set-up)
    for k in range(n):
        outp[k] = I[PRIM + k]
    if hits_out:
        inf = one / zero
        outt = out_t[lo:hi]
        outu = out_u[lo:hi]
        outv = out_v[lo:hi]
        for k in range(n):
            h = I[PRIM + k] >= 0
            outt[k] = F[BEST + k] if h else inf
            outu[k] = F[BU + k] if h else zero
            outv[k] = F[BV + k] if h else zero
    if counters.shape[0] > 0:
        for k in range(n):
            counters[lo + k, 0] = visited
            counters[lo + k, 1] = tested
    return over
