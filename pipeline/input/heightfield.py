"""Read a height field from an image, an array file or a mesh, with its sidecar.

Inputs: 8/16-bit grayscale PNG/TIFF (LA/RGBA alpha = 0 is outside; 32-bit
float TIFF too), ``.npy``/``.npz`` (float, millimetres, NaN outside) and
STL/OBJ/PLY/GLB meshes (top surface sampled on a grid from whichever side is up,
:mod:`pipeline.input.meshread`). Physical
scale comes from the optional sidecar ``NAME.yaml`` or the profile's
``defaults``. Everything a host should not trust is refused before it costs
memory: the declared pixel count is checked from the header before decoding.

Error codes (``InvalidHeightField``): ``heightfield.not_found``, ``.empty``,
``.unsupported_type`` (extension), ``.content_mismatch`` (bytes are not what
the extension says), ``.truncated``, ``.unreadable``, ``.too_many_pixels``,
``.pickled``, ``.bad_dtype``, ``.npz_key``, ``.not_2d``, ``.non_finite``,
``.no_footprint``, ``.flat``, ``.too_small``, ``.color_mismatch``,
``.not_a_heightfield`` (a mesh facing away from every axis). The
sidecar is read by :mod:`pipeline.input.sidecar`.
"""

import warnings
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.input.regular import opener
from pipeline.errors import InvalidHeightField
from pipeline.geometry import HeightField
from pipeline.profiles.schema import Defaults, ValidateParams
from pipeline.input import meshread
from pipeline.input.meshread import MESH_PIXEL_MM
from pipeline.input.sidecar import load_sidecar, sidecar_path

IMAGE_EXT = (".png", ".tif", ".tiff")
ARRAY_EXT = (".npy", ".npz")
MESH_EXT = (".stl", ".obj", ".ply", ".glb")

_MAGIC = {
    ".png": (b"\x89PNG\r\n\x1a\n",),
    ".tif": (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"),
    ".npy": (b"\x93NUMPY",),
    ".npz": (b"PK\x03\x04", b"PK\x05\x06"),
    ".glb": (b"glTF",),
    ".ply": (b"ply",),
}
_MAGIC[".tiff"] = _MAGIC[".tif"]


def _fail(code, msg, path, fix, where=None, **details):
    return InvalidHeightField(msg, code=code, file=path, where=where, fix=fix, details=details)


def load(path, profile=None, max_pixels=None):
    """Read an input file and its sidecar into a height field in millimetres.

    Parameters
    ----------
    path : str or Path
        ``.png``, ``.tif``/``.tiff``, ``.npy``, ``.npz``, ``.stl``, ``.obj``, ``.ply`` or ``.glb``.
    profile : pipeline.profiles.schema.Profile, optional
        Supplies ``defaults`` (scale without sidecar) and ``validate`` limits.
    max_pixels : int, optional
        Refuse inputs declaring more samples (default: the profile's
        ``validate.max_pixels``, else 25 million).

    Returns
    -------
    hf : HeightField
        ``z`` (rows, cols) float mm, minimum 0 on the footprint, NaN outside.
    sidecar : Sidecar
    """
    path = Path(path)
    name = str(path)
    ext = check_file(path)
    sidecar = load_sidecar(sidecar_path(path))
    # Without a profile, the profile schema's defaults apply.
    defaults, limits = (profile.defaults, profile.validate) if profile is not None else (
        Defaults(), ValidateParams())
    if max_pixels is None:
        max_pixels = limits.max_pixels

    color, up = None, None
    if ext in IMAGE_EXT:
        values = _read_image(path, max_pixels)
        # An image with no footprint is refused by _to_mm, with its own message.
        unit_height = (image_relief_mm(_pixel_mm(values, sidecar, defaults.size_mm), values,
                                       defaults) if np.isfinite(values).any() else 1.0)
    elif ext in ARRAY_EXT:
        values, unit_height = _read_array(path, ext, max_pixels), None
    else:
        values, color, pixel_mm, up = _read_mesh(path, sidecar, max_pixels)
        unit_height = None
    z = _to_mm(values, path, sidecar, unit_height)
    if ext not in MESH_EXT:
        pixel_mm = _pixel_mm(z, sidecar, defaults.size_mm)
    _check_size(z, path, limits.min_pixels)
    if color is None:
        color = _read_color(path, z.shape, max_pixels)
    return HeightField(z, float(pixel_mm), color=color, source=name, up=up), sidecar


def check_file(path):
    """The checks that need only a file's name and first bytes (it exists, is not empty, is
    of a type hostd reads, and its content is of that type): cheap enough to run on every
    file as it is taken, before a plan is spent on it. Returns the lower-case extension;
    raises :class:`InvalidHeightField`."""
    path = Path(path)
    name = str(path)
    if not path.is_file():
        raise _fail("heightfield.not_found", "input file not found", name,
                    "check the path" if not path.is_dir() else "give a file, not a directory")
    ext = path.suffix.lower()
    try:
        if path.stat().st_size == 0:
            raise _fail("heightfield.empty", "input file is empty (0 bytes)", name,
                        "the upload or copy did not finish; send the file again")
        if ext not in IMAGE_EXT + ARRAY_EXT + MESH_EXT:
            raise _fail("heightfield.unsupported_type", "unsupported input type %r" % ext, name,
                        "use a grayscale PNG/TIFF, .npy/.npz in mm, or an STL/OBJ/PLY/GLB mesh")
        _check_magic(path, ext)
    except OSError as exc:
        # The file's own fault (its permissions), not the share's: the daemon would take an
        # OSError here for the share failing, and stop taking every other file.
        raise _fail("heightfield.unreadable", "cannot read the input: %s"
                    % (exc.strerror or exc), name,
                    "make it readable to the user hostd runs as") from None
    return ext


def _check_magic(path, ext):
    # Opened without blocking and checked: the name may be a FIFO planted since the stat.
    with open(path, "rb", opener=opener) as f:
        head = f.read(512)
    magics = _MAGIC.get(ext)
    ok = any(head.startswith(m) for m in magics) if magics else True
    if ext == ".stl":
        # Binary STL has no magic; its triangle records are not text, a stray text file is.
        ok = head.lstrip().startswith(b"solid") or (
            _stl_binary_size(path) is not None and not (b"\x00" not in head and _is_text(head)))
    elif ext == ".obj":
        ok = b"\x00" not in head and _is_text(head)
    if not ok:
        raise _fail("heightfield.content_mismatch",
                    "the file's content is not %s data (starts with %r)" % (ext, head[:8]),
                    str(path), "rename it to its real type or export it again as %s" % ext)


def _is_text(head):
    try:
        head.decode("utf-8")
        return True
    except UnicodeDecodeError as exc:
        return exc.start > len(head) - 4  # a multi-byte character cut at the 512-byte mark


def _stl_binary_size(path):
    """Expected size of a binary STL from its face count, or None if it cannot be binary."""
    size = path.stat().st_size
    if size < 84:
        return None
    with open(path, "rb", opener=opener) as f:
        f.seek(80)
        n = int(np.frombuffer(f.read(4), "<u4")[0])
    return 84 + 50 * n


# A file declaring more than this many times the limit is not a big height field but a
# decompression bomb or a broken export: raising the limit is no fix for it.
_ABSURD = 4


def _too_many(path, pixels, max_pixels, what="image"):
    return _fail("heightfield.too_many_pixels",
                 "%s declares %s pixels, more than the limit of %s" % (what, pixels, max_pixels),
                 str(path), _too_many_fix(pixels, max_pixels),
                 pixels=pixels, max_pixels=max_pixels)


def _too_many_fix(pixels, max_pixels):
    if pixels is None or pixels > _ABSURD * max_pixels:
        return ("a sheet cannot show that much detail: export it again at most %d pixels "
                "(e.g. %d x %d); a file declaring far more than it holds is refused unread"
                % (max_pixels, int(max_pixels ** 0.5), int(max_pixels ** 0.5)))
    return "downsample it, or raise validate.max_pixels in the profile"


def _read_image(path, max_pixels):
    """Grey values (rows, cols) float in the file's own steps, NaN where alpha == 0."""
    name = str(path)
    try:
        with warnings.catch_warnings():
            # Our own limit is applied below; Pillow's warning would only be noise.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path)
    except Image.DecompressionBombError as exc:
        raise _fail("heightfield.too_many_pixels", "image header declares too many pixels (%s)"
                    % exc, name, _too_many_fix(None, max_pixels),
                    max_pixels=max_pixels) from None
    except Exception as exc:  # Pillow raises many types for broken headers
        raise _fail("heightfield.truncated", "image header cannot be read (%s)" % exc, name,
                    "the file is damaged or cut off; export it again") from None
    with im:
        w, h = im.size
        if w * h > max_pixels:
            raise _too_many(path, w * h, max_pixels)
        mode = im.mode
        try:
            im.load()
        except Exception as exc:
            raise _fail("heightfield.truncated", "image data is truncated or corrupt (%s)" % exc,
                        name, "the file is damaged or cut off; export it again") from None
        if mode == "P":
            im = im.convert("RGBA")
            mode = "RGBA"
        a = np.asarray(im)
    alpha = None
    if mode in ("RGB", "RGBA"):
        # Many tools save grey as RGB; only genuinely coloured heights are refused.
        rgb = a[..., :3]
        if not (np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])):
            raise _fail("heightfield.not_2d",
                        "image is in colour (%s); heights must be one grey channel" % mode, name,
                        "save the heights as 8/16-bit grayscale and any colour as NAME.color.png")
    elif mode not in ("L", "LA", "I", "F") and not mode.startswith("I;16"):
        raise _fail("heightfield.unsupported_type", "unsupported image mode %r" % mode, name,
                    "save as 8- or 16-bit grayscale (optionally with alpha)")
    if a.ndim == 3:
        if a.shape[2] in (2, 4):
            alpha = a[..., -1]
        a = a[..., 0]
    v = a.astype(np.float64)
    if alpha is not None:
        v[alpha == 0] = np.nan
    return v


def _npy_header(f):
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        return np.lib.format.read_array_header_1_0(f)
    return np.lib.format.read_array_header_2_0(f)


def _check_array_header(path, f, max_pixels, size_left=None):
    """Check an .npy header (shape, dtype) before reading any data."""
    name = str(path)
    try:
        shape, _, dtype = _npy_header(f)
    except Exception as exc:
        raise _fail("heightfield.truncated", "array header cannot be read (%s)" % exc, name,
                    "the file is damaged or cut off; save it again with numpy.save") from None
    if dtype.hasobject:
        raise _fail("heightfield.pickled", "the array holds Python objects (pickled data), which "
                    "are never loaded", name, "save a plain float array: np.save(path, z.astype(float))")
    if len(shape) != 2:
        raise _fail("heightfield.not_2d", "array has shape %s; a height field is 2-D (rows, cols)"
                    % (shape,), name, "save one 2-D float array of heights in mm")
    pixels = int(np.prod(shape))
    if pixels > max_pixels:
        raise _too_many(path, pixels, max_pixels, "array")
    if dtype.kind not in "fiu":
        raise _fail("heightfield.bad_dtype", "array type %s is not numeric heights" % dtype, name,
                    "save float heights in mm (NaN outside the footprint)")
    if size_left is not None and size_left - f.tell() < pixels * dtype.itemsize:
        raise _fail("heightfield.truncated", "array data is truncated (%d of %d bytes)"
                    % (size_left - f.tell(), pixels * dtype.itemsize), name,
                    "the file is cut off; save it again")


def _read_array(path, ext, max_pixels):
    name = str(path)
    if ext == ".npy":
        with open(path, "rb") as f:
            _check_array_header(path, f, max_pixels, path.stat().st_size)
        try:
            a = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise _fail("heightfield.truncated", "array cannot be read (%s)" % exc, name,
                        "save it again with numpy.save") from None
    else:
        try:
            with zipfile.ZipFile(path) as zf:
                keys = [n[:-4] for n in zf.namelist() if n.endswith(".npy")]
                key = keys[0] if len(keys) == 1 else next((k for k in ("z", "height") if k in keys),
                                                          None)
                if key is None:
                    raise _fail("heightfield.npz_key", "archive holds arrays %s; cannot tell which "
                                "is the height" % keys, name,
                                "store one array, or name it `z` or `height`")
                info = zf.getinfo(key + ".npy")
                with zf.open(info) as f:
                    _check_array_header(path, f, max_pixels, info.file_size)
            with np.load(path, allow_pickle=False) as npz:
                a = npz[key]
        except InvalidHeightField:
            raise
        except Exception as exc:
            raise _fail("heightfield.truncated", "archive cannot be read (%s)" % exc, name,
                        "the file is damaged or cut off; save it again with numpy.savez") from None
    return a.astype(np.float64)


def _to_mm(v, path, sidecar, unit_height_mm):
    """Heights in mm above the footprint's lowest point, NaN outside.

    ``unit_height_mm`` is the default maximum height for images (whose grey
    steps have no unit); None for inputs already in millimetres.
    """
    name = str(path)
    # Whole-array reductions, no copies of the inside values: a 16-megapixel map is
    # 128 MB per float64 copy, and printer hosts have 1-2 GB.
    if np.isnan(v).all():
        raise _fail("heightfield.no_footprint", "no valid samples: every value is NaN or "
                    "transparent", name, "mark the footprint with finite heights / opaque pixels")
    if np.isinf(v).any():
        r, c = np.argwhere(np.isinf(v))[0]
        raise _fail("heightfield.non_finite", "infinite height inside the footprint", name,
                    "replace inf by finite heights, or by NaN outside the footprint",
                    where="row %d, col %d" % (r, c))
    lo, hi = np.nanmin(v), np.nanmax(v)
    if hi - lo <= 0:
        raise _fail("heightfield.flat", "all heights are equal (%g): nothing to shape" % lo, name,
                    "a flat sheet needs no 4D print; check the export's bit depth and range")
    z = v
    z -= lo     # in place: the caller's array is not used again
    if sidecar.height_mm is not None:
        z *= sidecar.height_mm / (hi - lo)
    elif sidecar.height_scale is not None:
        z *= sidecar.height_scale  # per input unit: grey step, or the array's/mesh's unit
    elif unit_height_mm is not None:
        z *= unit_height_mm / (hi - lo)
    return z


def image_relief_mm(pixel_mm, values, defaults):
    """The relief of an image without a height: the profile's ``defaults.height_mm`` at
    ``defaults.size_mm``, in proportion at other sizes. Slopes and curvatures are what
    decide whether a sheet forms a shape, and they stay the same when the relief scales
    with the size: a 60 mm tile given the 30 mm of a 150 mm one is five times as steep."""
    h, w = _footprint_span(values)
    size = pixel_mm * max(h - 1, w - 1, 1)
    return defaults.height_mm * size / defaults.size_mm


def _pixel_mm(z, sidecar, default_size_mm):
    if sidecar.pixel_mm is not None:
        return sidecar.pixel_mm
    size_mm = sidecar.size_mm if sidecar.size_mm is not None else default_size_mm
    h, w = _footprint_span(z)
    return size_mm / max(h - 1, w - 1, 1)


def _footprint_span(z):
    """(rows, cols) the footprint spans; per-axis projections, not index lists, which
    would take 16 bytes per sample (256 MB on a 16-megapixel map)."""
    inside = np.isfinite(z)
    rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
    return rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1


def _check_size(z, path, min_pixels):
    h, w = _footprint_span(z)
    if min(h, w) < min_pixels:
        raise _fail("heightfield.too_small", "footprint is only %d x %d samples; at least %d per "
                    "side are needed to mesh it" % (h, w, min_pixels), str(path),
                    "use a larger image, or a smaller pixel_mm for meshes")


def _read_color(path, shape, max_pixels):
    """RGB (rows, cols, 3) uint8 from ``NAME.color.png`` resampled to the grid, or None."""
    cpath = path.with_name(path.stem + ".color.png")
    if not cpath.is_file():
        return None
    name = str(cpath)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(cpath) as im:
                if im.size[0] * im.size[1] > max_pixels:
                    raise _too_many(cpath, im.size[0] * im.size[1], max_pixels, "colour image")
                im.load()
                rgb = im.convert("RGB")
    except InvalidHeightField:
        raise
    except Exception as exc:
        raise _fail("heightfield.truncated", "colour image cannot be read (%s)" % exc, name,
                    "export NAME.color.png again as RGB(A) PNG") from None
    rows, cols = shape
    if abs(rgb.size[0] / rgb.size[1] - cols / rows) > 0.02 * cols / rows:
        raise _fail("heightfield.color_mismatch", "colour image is %dx%d but the heights are %dx%d "
                    "(different aspect)" % (rgb.size[0], rgb.size[1], cols, rows), name,
                    "crop the colour image to the height image's extent")
    return np.asarray(rgb.resize((cols, rows), Image.BILINEAR), dtype=np.uint8)



def _read_mesh(path, sidecar, max_pixels):
    """Top surface of a mesh, seen from its up side (:mod:`pipeline.input.meshread`):
    z (rows, cols) in mm (mesh units, scaled by ``size_mm``), colour (rows, cols, 3)
    uint8 or None, pixel_mm, and the report's ``up``."""
    import trimesh  # heavy import, only for mesh inputs

    name = str(path)
    with open(path, "rb") as f:
        ascii_stl = f.read(512).lstrip().startswith(b"solid")
    if path.suffix.lower() == ".stl" and not ascii_stl:
        expected = _stl_binary_size(path)
        if expected is not None and expected > path.stat().st_size:
            raise _fail("heightfield.truncated", "binary STL declares %d bytes of triangles but has "
                        "%d" % (expected - 84, path.stat().st_size - 84), name,
                        "the file is cut off; export it again")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:
        raise _fail("heightfield.unreadable", "mesh cannot be read (%s)" % exc, name,
                    "export it again as binary STL, PLY, OBJ or GLB") from None
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if len(faces) == 0:
        raise _fail("heightfield.no_footprint", "mesh has no triangles", name,
                    "export the surface as a triangle mesh")
    if not np.isfinite(verts).all():
        raise _fail("heightfield.non_finite", "mesh has non-finite vertex coordinates", name,
                    "repair the mesh")
    up, up_report = meshread.orientation(
        verts, faces, sidecar.up,
        lambda code, msg, fix, **details: _fail(code, msg, name, fix, **details))
    verts = meshread.turned_up(verts, up)
    span = np.ptp(verts[:, :2], axis=0).max()
    if sidecar.size_mm is not None and span > 0:
        verts = verts * (sidecar.size_mm / span)  # uniform: keeps the shape's proportions
    pixel_mm = sidecar.pixel_mm or MESH_PIXEL_MM

    def too_many(rows, cols):
        return _fail("heightfield.too_many_pixels", "sampling the mesh at %g mm needs %d x %d "
                     "samples, more than the limit of %d" % (pixel_mm, cols, rows, max_pixels),
                     name, "set a larger pixel_mm in the sidecar", pixels=int(rows * cols),
                     max_pixels=max_pixels)
    z, color = meshread.top_surface(verts, faces, pixel_mm, max_pixels, too_many,
                                    meshread.vertex_colors(mesh))
    return z, color, pixel_mm, up_report


def coarsen(hf, pixel_mm):
    """``hf`` averaged over whole k x k blocks, k the largest with k * hf.pixel_mm <= pixel_mm.

    A 16-megapixel height map of a 175 mm part has 0.04 mm samples; every stage
    after loading scales with the sample count (on this machine such a map took
    167 s and 6.1 GB, most of it in validation), while the sheet cannot form
    anything near that small (paths ~0.5 mm wide, ``smooth_mm`` ~1 mm). So the
    field is averaged over k x k blocks, k = floor(pixel_mm / hf.pixel_mm): a
    block is inside the footprint when at least half its samples are (the
    outline moves by under half a block), its height the mean of those samples,
    and its colour the mean colour. Fields already coarse enough, and
    ``pixel_mm`` 0, are returned as they are.

    Returns (HeightField, k).
    """
    k = int(np.floor(pixel_mm / hf.pixel_mm + 1e-9)) if pixel_mm > 0 else 1
    if k < 2:
        return hf, 1
    rows, cols = hf.z.shape
    R, C = -(-rows // k), -(-cols // k)

    def block_sums(a, dtype):
        # Padded to whole blocks; summing the (R, k, C, k) view copies nothing more.
        pad = np.zeros((R * k, C * k), dtype=dtype)
        pad[:rows, :cols] = a
        return pad.reshape(R, k, C, k).sum(axis=(1, 3))

    inside = np.isfinite(hf.z)
    count = block_sums(inside, np.int32)
    total = block_sums(np.where(inside, hf.z, 0.0), np.float64)
    keep = 2 * count >= k * k
    z = np.where(keep, total / np.maximum(count, 1), np.nan)
    z -= np.nanmin(z)
    color = None
    if hf.color is not None:
        color = np.stack([block_sums(np.where(inside, hf.color[..., c], 0), np.int32)
                          for c in range(3)], axis=-1)
        color = np.clip(np.rint(color / np.maximum(count, 1)[..., None]), 0, 255).astype(np.uint8)
    return HeightField(z, hf.pixel_mm * k, color=color, source=hf.source), k
