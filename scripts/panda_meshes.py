#!/usr/bin/env python3
"""Convert the Panda's visual meshes (links 0-7, hand, finger) of the
`example-robot-data` package (PyPI, panda_description: Apache-2.0, from
franka_description) from Collada to OBJ, which MuJoCo 2.2 loads, for the
renderer's visual-only geoms.

Usage:  python3 scripts/panda_meshes.py [outdir]      (default: assets/meshes)
        python3 scripts/panda_meshes.py --requirements   (the pinned packages, for pip)
        python3 scripts/panda_meshes.py --check          (exit 2 unless they are installed)

The package is a dependency installed by ./dev; nothing from it is committed.
Only the geometry is kept (triangles, all <node> transforms applied, in metres):
the original D3IL scene draws these meshes in plain colours (white at alpha 0.1
for the links, MuJoCo's default grey for the hand and fingers), not with the
Collada materials (docs/original-d3il.md §01.2.5, §01.6).

The original loads these meshes as STL files (docs/original-d3il.md §01.2.5),
whose repeated vertices MuJoCo merges before computing smooth vertex normals;
MuJoCo 2.2 gives every OBJ face vertices of its own instead, so an OBJ without
normals is drawn flat-shaded (with the full meshes flat, the front camera was
0.38/255 from the original's frames; with these normals 0.05/255). The
converter therefore merges equal vertices as MuJoCo's STL loader does and
writes each vertex's normal as MuJoCo computes it (mjCMesh::MakeNormal: the
area-weighted face normals, without the faces more than about 37 degrees off
their average), which MuJoCo then uses as given.

The full meshes have 12 000-22 000 triangles per link, which at 96x96 pixels
are mostly far smaller than a pixel (the front view drew 92 ms per frame with
them). Meshes above their budget (BUDGET: 2 000 triangles for a link, 3 000 for
the hand) are therefore reduced to it by
quadric edge collapse with MeshLab's filter (the `pymeshlab` package, pinned in
REQUIREMENTS with explicit parameters, so every machine gets the same
vertices); docs/images.md gives the measured difference to the original's
frames and to frames drawn with the full meshes, which are written too, to
outdir/full/, for the test that keeps that difference small
(evaluator/tests/simulator/panda_meshes.rs).

Exits with status 2 and a message naming the packages when the pinned versions
are not installed.
"""

import os
import struct
import sys
import xml.etree.ElementTree as ET

PARTS = [f"link{i}" for i in range(8)] + ["hand", "finger"]
# Triangles kept per mesh: the links (translucent, drawn in both of MuJoCo's
# transparent passes) 2 000, the opaque hand, drawn once, 3 000 (it costs half
# as much per triangle and is the part of the front view reduction shows most).
BUDGET = {"hand": 3000}
LINK_BUDGET = 2000
# The packages the meshes come from, pinned: the committed meshed frames
# (tests/cli/render_golden.rs) depend on the exact vertices. ./dev installs these.
REQUIREMENTS = {"example-robot-data": "6.0.0", "pymeshlab": "2025.7.post1"}
# MeshLab's quadric edge collapse, every parameter given (its defaults), so a
# change of defaults in another version cannot change the vertices silently.
DECIMATION = dict(qualitythr=0.3, preserveboundary=False, boundaryweight=1.0,
                  preservenormal=False, preservetopology=False, optimalplacement=True,
                  planarquadric=False, planarweight=0.001, qualityweight=False,
                  autoclean=True, selected=False)


def pins():
    """REQUIREMENTS as pip arguments."""
    return " ".join(f"{n}=={v}" for n, v in REQUIREMENTS.items())


def check_requirements():
    """Exit 2 naming what to install unless the pinned versions are installed."""
    from importlib import metadata
    wrong = []
    for name, version in REQUIREMENTS.items():
        try:
            have = metadata.version(name)
        except metadata.PackageNotFoundError:
            have = None
        if have != version:
            wrong.append(f"{name}=={version} (installed: {have or 'none'})")
    if wrong:
        print("the Panda meshes need " + ", ".join(wrong) + ": pip install " + pins()
              + " (./dev does); without them the renderer keeps the primitive robot",
              file=sys.stderr)
        sys.exit(2)


NS = "{http://www.collada.org/2005/11/COLLADASchema}"


def package_dir():
    """The panda_description/meshes/visual folder of the installed package."""
    try:
        from importlib import metadata
        dist = metadata.distribution("example-robot-data")
    except Exception:  # noqa: BLE001 - any lookup failure means "not installed"
        return None
    for f in dist.files or []:
        p = str(f).replace("\\", "/")
        if p.endswith("panda_description/meshes/visual/hand.dae"):
            return os.path.dirname(str(dist.locate_file(f)))
    return None


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def node_matrix(node):
    m = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    for child in node:
        if child.tag == NS + "matrix":
            v = [float(x) for x in child.text.split()]
            m = mat_mul(m, [v[0:4], v[4:8], v[8:12], v[12:16]])
        elif child.tag in (NS + "translate", NS + "rotate", NS + "scale"):
            raise SystemExit(f"unsupported Collada transform <{child.tag[len(NS):]}>; only <matrix> is handled")
    return m


def read_collada(path):
    """Triangles of every instanced geometry, in metres, as (vertices, faces)."""
    root = ET.parse(path).getroot()
    unit = root.find(f"{NS}asset/{NS}unit")
    scale = float(unit.get("meter", "1")) if unit is not None else 1.0
    up = root.find(f"{NS}asset/{NS}up_axis")
    if up is not None and up.text.strip() != "Z_UP":
        raise SystemExit(f"{path}: up axis {up.text.strip()} (only Z_UP is handled)")
    geoms = {g.get("id"): g for g in root.iter(NS + "geometry")}
    verts, faces = [], []

    def walk(node, parent):
        m = mat_mul(parent, node_matrix(node))
        for inst in node.findall(NS + "instance_geometry"):
            add_geometry(geoms[inst.get("url").lstrip("#")], m)
        for child in node.findall(NS + "node"):
            walk(child, m)

    def add_geometry(geom, m):
        mesh = geom.find(NS + "mesh")
        sources = {s.get("id"): [float(x) for x in s.find(NS + "float_array").text.split()]
                   for s in mesh.findall(NS + "source")}
        vin = mesh.find(NS + "vertices")
        pos_src = next(i.get("source") for i in vin.findall(NS + "input") if i.get("semantic") == "POSITION")
        pos = sources[pos_src.lstrip("#")]
        base = len(verts)
        for k in range(0, len(pos), 3):
            x, y, z = pos[k:k + 3]
            verts.append(tuple(scale * (m[r][0] * x + m[r][1] * y + m[r][2] * z + m[r][3]) for r in range(3)))
        for tri in mesh.findall(NS + "triangles"):
            inputs = tri.findall(NS + "input")
            stride = max(int(i.get("offset")) for i in inputs) + 1
            voff = next(int(i.get("offset")) for i in inputs if i.get("semantic") == "VERTEX")
            idx = [int(x) for x in tri.find(NS + "p").text.split()]
            corners = idx[voff::stride]
            for k in range(0, len(corners) - 2, 3):
                faces.append((base + corners[k], base + corners[k + 1], base + corners[k + 2]))
        if mesh.find(NS + "polylist") is not None or mesh.find(NS + "polygons") is not None:
            raise SystemExit(f"{path}: <polylist>/<polygons> are not handled")

    ident = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    for scene in root.iter(NS + "visual_scene"):
        for node in scene.findall(NS + "node"):
            walk(node, ident)
    return verts, faces


def _merge(verts, faces, key):
    """Vertices with the same key merged into the first of them (its
    coordinates kept) and faces that become degenerate dropped."""
    index, out, welded = {}, [], []
    for v in verts:
        k = key(v)
        if k not in index:
            index[k] = len(out)
            out.append(v)
        welded.append(index[k])
    tris = [(welded[a], welded[b], welded[c]) for a, b, c in faces]
    return out, [t for t in tris if len(set(t)) == 3]


def weld(verts, faces):
    """Merge vertices at the same position (to 1e-6 m; Collada repeats them per
    face) and drop faces that become degenerate, so edges can be collapsed."""
    return _merge(verts, faces, lambda v: tuple(round(c * 1e6) for c in v))


def _float32(v):
    return tuple(struct.unpack("<3f", struct.pack("<3f", *v)))


def merge_equal(verts, faces):
    """Vertices with equal float32 coordinates merged into one and faces that
    become degenerate dropped, as MuJoCo's STL loader does (RemoveRepeated)."""
    out, tris = _merge(verts, faces, _float32)
    return [_float32(v) for v in out], tris


def vertex_normals(verts, faces):
    """MuJoCo's vertex normals for a mesh without any (mjCMesh::MakeNormal with
    smoothnormal false): each vertex sums its faces' unit normals weighted by
    their area, then the faces whose normal has a dot product below 0.8 with
    that sum's direction are taken out again (sharp edges stay sharp), and
    the result is normalised ((0, 0, 1) if nothing is left)."""
    import numpy as np
    v = np.array(verts, dtype=np.float64)
    f = np.array(faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area = np.linalg.norm(cross, axis=1)
    unit = cross / np.where(area > 0, area, 1.0)[:, None]
    weighted = unit * area[:, None]
    total = np.zeros_like(v)
    for j in range(3):
        np.add.at(total, f[:, j], weighted)
    removed = np.zeros_like(v)
    for j in range(3):
        at = total[f[:, j]]
        length = np.linalg.norm(at, axis=1)
        direction = at / np.where(length > 0, length, 1.0)[:, None]
        far = (direction * unit).sum(axis=1) < 0.8
        np.add.at(removed, f[far, j], weighted[far])
    n = total - removed
    length = np.linalg.norm(n, axis=1)
    n = np.where(length[:, None] > 1e-15, n / np.where(length > 0, length, 1.0)[:, None],
                 np.array([0.0, 0.0, 1.0]))
    return [tuple(float(c) for c in row) for row in n]


def reduce(verts, faces, budget):
    """The mesh with at most `budget` triangles (unchanged when it has fewer)."""
    if len(faces) <= budget:
        return verts, faces
    import numpy as np
    import pymeshlab
    verts, faces = weld(verts, faces)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.array(verts, dtype=np.float64), np.array(faces, dtype=np.int32)))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=budget, **DECIMATION)
    m = ms.current_mesh()
    return ([tuple(float(c) for c in p) for p in m.vertex_matrix()],
            [tuple(int(i) for i in t) for t in m.face_matrix()])


def write_obj(path, verts, faces, source):
    """Vertices (equal ones merged) with MuJoCo's normals, and the faces."""
    verts, faces = merge_equal(verts, faces)
    # Drop vertices no face uses and renumber (MuJoCo counts every vertex).
    used = sorted({i for f in faces for i in f})
    new = {old: k + 1 for k, old in enumerate(used)}
    kept = [verts[i] for i in used]
    normals = vertex_normals(kept, [tuple(new[i] - 1 for i in f) for f in faces])
    with open(path, "w") as f:
        f.write(f"# converted by scripts/panda_meshes.py from {source}\n")
        for p in kept:
            f.write("v %.7g %.7g %.7g\n" % p)
        for n in normals:
            f.write("vn %.7g %.7g %.7g\n" % n)
        for a, b, c in faces:
            a, b, c = new[a], new[b], new[c]
            f.write(f"f {a}//{a} {b}//{b} {c}//{c}\n")
    return len(faces)


def main():
    if sys.argv[1:] == ["--requirements"]:
        print(pins())
        return
    if sys.argv[1:] == ["--check"]:
        check_requirements()
        return
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "assets", "meshes")
    check_requirements()
    src = package_dir()
    if src is None:
        print("example-robot-data has no panda_description/meshes/visual", file=sys.stderr)
        sys.exit(2)
    full = os.path.join(out, "full")
    os.makedirs(full, exist_ok=True)
    for part in PARTS:
        verts, faces = read_collada(os.path.join(src, part + ".dae"))
        lo = [min(v[k] for v in verts) for k in range(3)]
        hi = [max(v[k] for v in verts) for k in range(3)]
        source = f"example-robot-data panda_description/meshes/visual/{part}.dae"
        write_obj(os.path.join(full, f"panda_{part}.obj"), verts, faces, source)
        rv, rf = reduce(verts, faces, BUDGET.get(part, LINK_BUDGET))
        path = os.path.join(out, f"panda_{part}.obj")
        n = write_obj(path, rv, rf, f"{source}, reduced to {len(rf)} triangles")
        print(f"{path}: {n} of {len(faces)} triangles, bounds x [{lo[0]:.4f}, {hi[0]:.4f}] "
              f"y [{lo[1]:.4f}, {hi[1]:.4f}] z [{lo[2]:.4f}, {hi[2]:.4f}]")


if __name__ == "__main__":
    main()
