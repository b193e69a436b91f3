#!/usr/bin/env python3
"""Check an OpenVDB file written by `eikon export` with OpenVDB itself.

usage: vdb_check.py FILE.vdb NPY_DIR [--half]

NPY_DIR is the `--npy` output of the same export: `volumes.json` and one
`.npy` file per grid. Using pyopenvdb (OpenVDB's Python module) and NumPy,
this checks, exactly (no tolerance on values):

* the file holds exactly the grids of volumes.json, each with its type
  (FloatGrid or Vec3SGrid), class, vector type, background and half-float
  flag;
* each .npy file loads with dtype float32, shape (nx, ny, nz) or
  (nx, ny, nz, 3), C order;
* the active voxels (tiles counted voxel by voxel) are exactly the voxels
  whose .npy value differs from the background, and every value read by
  OpenVDB at index (i, j, k) equals array[i, j, k] (rounded to half
  precision with --half); inactive voxels read as the background;
* the transform puts voxel (i, j, k) at min + (i + 0.5, j + 0.5, k + 0.5) *
  spacing, and worldToIndexCellCentered maps that point back to (i, j, k);
* the metadata file_bbox_min/max and file_voxel_count agree with the grid;
* volumes.json (version 2) names a run id, and every .npy file has the size
  and CRC-32 (zlib's) it records, and every volume's file is among them.

Prints one line per grid, then `ok`; on the first difference prints what
differs and exits with status 1.
"""

import json
import os
import sys
import zlib

import numpy as np
import pyopenvdb as vdb


def fail(msg):
    print("FAIL: " + msg)
    sys.exit(1)


def check(path, npy_dir, half):
    with open(os.path.join(npy_dir, "volumes.json")) as f:
        side = json.load(f)
    if side.get("version") != 2 or len(side.get("run_id", "")) != 16:
        fail("volumes.json: version %r, run id %r" % (side.get("version"), side.get("run_id")))
    records = {r["name"]: r for r in side["files"]}
    for v in side["volumes"]:
        if v["file"] not in records:
            fail("%s: not among the files volumes.json records" % v["file"])
    for name, r in records.items():
        with open(os.path.join(npy_dir, name), "rb") as f:
            data = f.read()
        if len(data) != r["bytes"] or "%08x" % zlib.crc32(data) != r["crc32"]:
            fail("%s: %d bytes, CRC-32 %08x; volumes.json records %d, %s"
                 % (name, len(data), zlib.crc32(data), r["bytes"], r["crc32"]))
    dims = side["grid"]["dims"]
    lo = np.array(side["grid"]["min"], dtype=np.float64)
    spacing = np.array(side["grid"]["spacing"], dtype=np.float64)
    grids, file_meta = vdb.readAll(path)
    if file_meta.get("creator") != "eikon":
        fail("file metadata creator: %r" % file_meta.get("creator"))
    by_name = {g.name: g for g in grids}
    want = [v["name"] for v in side["volumes"]]
    if sorted(by_name) != sorted(want) or len(grids) != len(want):
        fail("grids %s, expected %s" % (sorted(by_name), sorted(want)))

    for v in side["volumes"]:
        name = v["name"]
        g = by_name[name]
        arr = np.load(os.path.join(npy_dir, v["file"]))
        vector = len(v["shape"]) == 4
        shape = tuple(dims) + ((3,) if vector else ())
        if arr.dtype != np.float32 or arr.shape != shape or list(arr.shape) != v["shape"]:
            fail("%s.npy: dtype %s shape %s, expected float32 %s" % (name, arr.dtype, arr.shape, shape))
        if not arr.flags["C_CONTIGUOUS"]:
            fail("%s.npy: not C order" % name)
        kind = "Vec3SGrid" if vector else "FloatGrid"
        if type(g).__name__ != kind:
            fail("%s: %s, expected %s" % (name, type(g).__name__, kind))
        if g.saveFloatAsHalf != half:
            fail("%s: saveFloatAsHalf %s, expected %s" % (name, g.saveFloatAsHalf, half))
        meta = g.metadata
        if meta.get("is_saved_as_half_float") != half:
            fail("%s: metadata is_saved_as_half_float %r" % (name, meta.get("is_saved_as_half_float")))
        if meta.get("class") != v["class"]:
            fail("%s: class %r, expected %r" % (name, meta.get("class"), v["class"]))
        if vector and g.vectorType != v["vector_type"]:
            fail("%s: vector type %r, expected %r" % (name, g.vectorType, v["vector_type"]))

        bg = np.array(v["background"], dtype=np.float32)
        got_bg = np.array(g.background, dtype=np.float32)
        def to_half(a):
            if not half:
                return a
            # Beyond +-65504 a half float is infinite, in OpenVDB as in NumPy.
            with np.errstate(over="ignore"):
                return a.astype(np.float16).astype(np.float32)
        if not np.array_equal(got_bg, to_half(bg)):
            fail("%s: background %s, expected %s" % (name, got_bg, to_half(bg)))

        # Active voxels: exactly those that differ from the background.
        differs = arr != bg
        if vector:
            differs = differs.any(axis=3)
        active = np.zeros(tuple(dims), dtype=bool)
        count = 0
        for item in g.citerOnValues():
            a, b = np.array(item["min"]), np.array(item["max"])
            if (a < 0).any() or (b >= np.array(dims)).any():
                fail("%s: active value at %s..%s outside the grid %s" % (name, a, b, dims))
            active[a[0]:b[0] + 1, a[1]:b[1] + 1, a[2]:b[2] + 1] = True
            count += item["count"]
        if count != g.activeVoxelCount() or count != int(active.sum()):
            fail("%s: %d active values, activeVoxelCount %d, %d distinct voxels"
                 % (name, count, g.activeVoxelCount(), active.sum()))
        if not np.array_equal(active, differs):
            i = np.argwhere(active != differs)[0]
            fail("%s: voxel %s active=%s but differs from the background=%s"
                 % (name, tuple(i), active[tuple(i)], differs[tuple(i)]))

        # Every value, exactly (inactive ones are the background).
        got = np.zeros(shape, dtype=np.float32)
        g.copyToArray(got, ijk=(0, 0, 0))
        expect = np.where(active[..., None] if vector else active, to_half(arr), to_half(bg))
        if not np.array_equal(got, expect):
            i = np.argwhere(got != expect)[0]
            fail("%s: value at %s is %r, expected %r" % (name, tuple(i), got[tuple(i)], expect[tuple(i)]))

        # Where the voxels are.
        for ijk in [(0, 0, 0), tuple(d - 1 for d in dims), (dims[0] // 2, 1, dims[2] - 1)]:
            centre = lo + (np.array(ijk) + 0.5) * spacing
            w = np.array(g.transform.indexToWorld(ijk))
            if np.abs(w - centre).max() > 1e-12 * (1 + np.abs(centre).max()):
                fail("%s: voxel %s at %s, expected the cell centre %s" % (name, ijk, w, centre))
            back = g.transform.worldToIndexCellCentered(tuple(centre))
            if tuple(back) != ijk:
                fail("%s: world %s maps to voxel %s, expected %s" % (name, centre, back, ijk))
        vs = np.array(g.transform.voxelSize())
        if np.abs(vs - spacing).max() > 1e-12 * spacing.max():
            fail("%s: voxel size %s, expected %s" % (name, vs, spacing))

        # Statistics metadata.
        if count:
            bmin, bmax = g.evalActiveVoxelBoundingBox()
            if tuple(meta["file_bbox_min"]) != tuple(bmin) or tuple(meta["file_bbox_max"]) != tuple(bmax):
                fail("%s: file_bbox %s..%s, active box %s..%s"
                     % (name, meta["file_bbox_min"], meta["file_bbox_max"], bmin, bmax))
        if meta["file_voxel_count"] != count:
            fail("%s: file_voxel_count %s, expected %d" % (name, meta["file_voxel_count"], count))
        print("%-12s %-9s %9d active voxels, exact" % (name, kind, count))
    print("ok")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if len(args) != 2:
        print(__doc__)
        sys.exit(2)
    check(args[0], args[1], "--half" in sys.argv[1:])
