"""Binary PLY writer for triangle meshes with optional vertex colours and scalars.

Written by hand (one header, two numpy record arrays) because it is short, fast
and keeps vertex order exactly: trimesh's exporter goes through a ``Trimesh``
object, which merges and reorders vertices unless told otherwise.
"""

import io
import os

import numpy as np



def ply_bytes(vertices, faces, vertex_colors=None, vertex_scalars=None, double=False,
              comment="hostd"):
    """The PLY file as bytes (binary little-endian).

    Parameters
    ----------
    vertices : (n, 3) float, mm
    faces : (m, 3) int
    vertex_colors : (n, 3) or (n, 4) uint8, optional
        Written as ``red green blue [alpha]`` uchar properties.
    vertex_scalars : dict name -> (n,) float, optional
        Extra per-vertex float properties (e.g. ``{"quality": displacement_mm}``,
        which MeshLab shows as vertex quality).
    double : bool
        Write coordinates as float64 instead of float32.
    comment : str
        One header comment line (ASCII, no newlines).

    Returns
    -------
    bytes
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must be (n, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces must be (m, 3), got {f.shape}")
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError("faces index outside the vertex array")
    ctype = "<f8" if double else "<f4"
    fields = [("x", ctype), ("y", ctype), ("z", ctype)]
    if vertex_colors is not None:
        c = np.asarray(vertex_colors)
        if c.shape not in ((len(v), 3), (len(v), 4)):
            raise ValueError(f"vertex_colors must be (n, 3) or (n, 4), got {c.shape}")
        if c.dtype != np.uint8:
            c = np.clip(np.round(c), 0, 255).astype(np.uint8)
        fields += [(k, "u1") for k in ("red", "green", "blue", "alpha")[: c.shape[1]]]
    scalars = {k: np.asarray(s, dtype=np.float32).reshape(-1) for k, s in (vertex_scalars or {}).items()}
    for k, s in scalars.items():
        if len(s) != len(v) or not k.isidentifier():
            raise ValueError(f"vertex scalar {k!r} must be a (n,) array with a plain name")
        fields.append((k, "<f4"))
    rec = np.empty(len(v), dtype=fields)
    rec["x"], rec["y"], rec["z"] = v[:, 0], v[:, 1], v[:, 2]
    if vertex_colors is not None:
        for k, name in enumerate(("red", "green", "blue", "alpha")[: c.shape[1]]):
            rec[name] = c[:, k]
    for k, s in scalars.items():
        rec[k] = s
    frec = np.empty(len(f), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    frec["n"] = 3
    frec["v"] = f

    names = {"<f4": "float", "<f8": "double", "u1": "uchar"}
    head = ["ply", "format binary_little_endian 1.0", f"comment {comment}",
            f"element vertex {len(v)}"]
    head += [f"property {names[t]} {k}" for k, t in fields]
    head += [f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(head) + "\n").encode("ascii") + rec.tobytes() + frec.tobytes()


def write_ply(path, vertices, faces, vertex_colors=None, vertex_scalars=None, double=False):
    """Write a binary little-endian PLY mesh.

    Parameters
    ----------
    path : str, os.PathLike or binary file object
        The caller does atomic replacement (temp name, then rename) if it needs it.
    vertices : (n, 3) float, mm
    faces : (m, 3) int
    vertex_colors : (n, 3) or (n, 4) uint8, optional
    vertex_scalars : dict name -> (n,) float, optional
    double : bool
        float64 coordinates (default float32, ~1e-5 mm resolution at 200 mm).

    Returns
    -------
    int : bytes written.
    """
    data = ply_bytes(vertices, faces, vertex_colors, vertex_scalars, double)
    if isinstance(path, (str, os.PathLike)):
        with open(path, "wb") as fh:
            fh.write(data)
    elif isinstance(path, io.TextIOBase):
        raise TypeError("write_ply needs a binary file object (open with 'wb')")
    else:
        path.write(data)
    return len(data)
