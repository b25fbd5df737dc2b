"""The ``hwrt`` command line (SPEC section 8).

Every subcommand takes ``--json`` and then prints exactly one JSON object on stdout; progress
and logs go to stderr. Exit status: 0 success, 2 bad input (one-line error on stderr), 1 other.
"""
import argparse
import json
import os
import sys

from hwbvh import config
from hwbvh.errors import InputError


def _emit(args, result, human):
    if args.json:
        sys.stdout.write(json.dumps(result) + "\n")
    else:
        sys.stdout.write(human(result) + "\n")
    sys.stdout.flush()


def _kv(result, keys):
    return "\n".join(f"{k:>18}: {result[k]}" for k in keys if k in result)


# --------------------------------------------------------------------------------------
def cmd_build(args):
    from hwbvh.api import build, save, write_files
    from hwbvh.primitives import pack_records, primitive_boxes

    if args.builder == "embree":
        from traversal.embree_ref import embree_build_seconds
        from hwbvh.primitives import load_mesh_arrays, as_triangles
        verts, faces = load_mesh_arrays(args.mesh)
        as_triangles(verts[faces], source=args.mesh)
        if args.out or args.dump_aabbs or args.dump_handoff:
            raise InputError("--builder embree", "Embree's tree is internal to Embree: "
                             "--out and the dumps need --builder hwbvh or sweep")
        secs = embree_build_seconds(verts, faces)
        result = {"triangles": int(len(faces)), "nodes": None, "leaves": None, "max_depth": None,
                  "sah_cost": None, "build_seconds": secs, "fallback_splits": None,
                  "builder": "embree"}
        return _emit(args, result, lambda r: _kv(r, r.keys()))
    bvh = build(args.mesh, builder=args.builder, leaf_size=args.leaf_size, bins=args.bins,
                capacity=args.capacity, subtree_builders=args.subtree_builders,
                block_nodes=args.block_nodes, validate_tree=True)
    result = dict(bvh.meta)
    outputs = []
    if args.dump_aabbs or args.dump_handoff:
        boxes = primitive_boxes(bvh.triangles)
        files = []
        if args.dump_aabbs:
            files.append((args.dump_aabbs, pack_records(boxes)))
        if args.dump_handoff:
            order, sizes = bvh.handoff_order()
            files.append((args.dump_handoff, pack_records(boxes, order)))
            files.append((args.dump_handoff + ".json",
                          json.dumps({"record_bytes": config.PRIMITIVE_RECORD_BYTES,
                                      "handoff_sizes": [int(x) for x in sizes]}) + "\n"))
            result["handoff_sizes"] = [int(x) for x in sizes]
        write_files(files)
        outputs += [f for f, _ in files]
    if args.out:
        outputs += save(bvh, args.out)
    result["outputs"] = outputs
    keys = ["builder", "triangles", "nodes", "leaves", "max_depth", "sah_cost", "fallback_splits",
            "build_seconds", "handoffs", "outputs"]
    _emit(args, result, lambda r: _kv(r, keys))


def cmd_bench(args):
    from . import bench
    fn = {"build": bench.bench_build, "scale": bench.bench_scale}.get(args.what)
    if fn is None:
        raise InputError("bench", f"'{args.what}' is not available yet")
    result = fn(args)
    _emit(args, result, bench.human(args.what))


# --------------------------------------------------------------------------------------
def _positive(v):
    try:
        i = int(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{v!r} is not an integer")
    return i


def make_parser():
    p = argparse.ArgumentParser(prog="hwrt", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build", help="build a BVH over a mesh (SPEC 8)")
    b.add_argument("mesh")
    b.add_argument("--builder", choices=["hwbvh", "sweep", "embree"], default="hwbvh")
    b.add_argument("--leaf-size", type=_positive, default=config.DEFAULT_LEAF_SIZE)
    b.add_argument("--bins", type=_positive, default=config.DEFAULT_BINS)
    b.add_argument("--capacity", type=_positive, default=config.DEFAULT_CAPACITY,
                   help="subtree capacity w*Psize (placement only; the tree never changes)")
    b.add_argument("--subtree-builders", type=_positive, default=1)
    b.add_argument("--block-nodes", type=_positive, default=config.DEFAULT_BLOCK_NODES)
    b.add_argument("--out", metavar="PREFIX", help="write PREFIX.nodes/.indices/.json")
    b.add_argument("--dump-aabbs", metavar="F", help="primitive records as the hardware reads them")
    b.add_argument("--dump-handoff", metavar="F", help="records in upper-builder hand-off order")
    b.add_argument("--json", action="store_true")
    b.set_defaults(func=cmd_build)

    be = sub.add_parser("bench", help="benchmarks against peers measured in the same run")
    be.add_argument("what", choices=["build", "scale", "trace", "tti", "accuracy"])
    be.add_argument("meshes", nargs="*", help="mesh files (default: every mesh in --mesh-dir)")
    be.add_argument("--mesh-dir", help="default: $HWRT_MESHES or ../shared/meshes, else generated")
    be.add_argument("--repeat", type=_positive, default=5)
    be.add_argument("--json", action="store_true")
    be.set_defaults(func=cmd_bench)
    return p


def main(argv=None):
    parser = make_parser()
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except InputError as e:
        print(f"hwrt: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hwrt: interrupted", file=sys.stderr)
        return 1
    except Exception as e:  # anything else is our fault, not the input's
        print(f"hwrt: internal error: {type(e).__name__}: {e}", file=sys.stderr)
        if os.environ.get("HWRT_DEBUG"):
            raise
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
