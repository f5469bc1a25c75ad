"""Gaussians to and from the standard 3DGS ``.ply`` layout (INRIA ``gaussian-splatting``).

One ``vertex`` element, binary little-endian, every property a ``float`` (float32), in this order::

    x y z                      mean (world frame, metres)
    nx ny nz                   zeros (the INRIA code writes them; some viewers expect them)
    f_dc_0 f_dc_1 f_dc_2       SH degree-0 coefficient per channel: (rgb - 0.5) / C0
    f_rest_0 .. f_rest_{K-1}   higher SH coefficients, K = 3 * ((deg + 1)^2 - 1), channel-major:
                               all of R's coefficients, then G's, then B's (zeros here: our
                               Gaussians have view-independent colour)
    opacity                    opacity logit (viewers apply a sigmoid)
    scale_0 scale_1 scale_2    log of the scales (viewers apply exp)
    rot_0 rot_1 rot_2 rot_3    rotation quaternion w x y z (viewers normalise it)

SuperSplat, the INRIA SIBR viewer and gsplat's exporters read and write this layout. Degree 3 (45
``f_rest``) is what most viewers assume, so it is the default even though the extra coefficients
are zeros.

The PLY header and body are written and parsed by hand with numpy rather than with the ``plyfile``
package: the layout is fixed and tiny, and one dependency fewer keeps the install light.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from radar4dgs.io.atomic import atomic_write_bytes

# Degree-0 real spherical harmonic, 1 / (2 sqrt(pi)): the 3DGS colour of a DC coefficient f is
# 0.5 + C0 * f.
SH_C0 = 0.28209479177387814

MAX_SH_DEGREE = 3

# PLY scalar type names (both spellings of the spec) -> numpy type codes without byte order.
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}

# A real header is a few hundred lines at most; the cap stops a non-PLY file from being read whole.
_MAX_HEADER_LINES = 10_000


def num_rest_coefficients(sh_degree: int) -> int:
    """Number of ``f_rest_*`` properties for an SH degree: ``3 * ((sh_degree + 1)^2 - 1)``."""
    return 3 * ((sh_degree + 1) ** 2 - 1)


def property_names(sh_degree: int = 3) -> list[str]:
    """The vertex property names, in file order, for ``sh_degree``."""
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(num_rest_coefficients(sh_degree))]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def _to_numpy(name: str, value: Any) -> np.ndarray:
    # torch is not imported here: tensors are recognised by their ``detach`` method, so exporting
    # numpy arrays never loads torch.
    if hasattr(value, "detach") and hasattr(value, "cpu"):
        tensor = value.detach().cpu()
        if tensor.is_floating_point():
            tensor = tensor.float()  # half / bfloat16 have no numpy counterpart usable here
        value = tensor.numpy()
    try:
        array = np.asarray(value)
    except Exception as exc:  # noqa: BLE001 - any conversion failure is a bad input
        raise TypeError(f"{name}: cannot convert {type(value).__name__} to an array: {exc}") from exc
    if array.dtype == object or not (np.issubdtype(array.dtype, np.floating)
                                     or np.issubdtype(array.dtype, np.integer)):
        raise TypeError(f"{name}: expected a real numeric array, got dtype {array.dtype}")
    return array.astype(np.float64, copy=False)


def _check(name: str, array: np.ndarray, shape: tuple[int, ...]) -> None:
    if array.shape != shape:
        raise ValueError(f"{name} has shape {array.shape}, expected {shape}")
    bad = ~np.isfinite(array)
    if bad.any():
        rows = np.unique(np.nonzero(bad)[0])
        raise ValueError(f"{name} has {len(rows)} row(s) with NaN or inf values "
                         f"(first at index {int(rows[0])})")


def write_gaussians_ply(path: str | os.PathLike, means: Any, quats: Any, log_scales: Any,
                        opacity_logits: Any, rgb: Any, sh_degree: int = 3) -> Path:
    """Write N Gaussians as a standard 3DGS binary little-endian ``.ply``; returns the path.

    ``means`` (N, 3) world metres, ``quats`` (N, 4) wxyz (any non-zero norm: written as given,
    viewers normalise), ``log_scales`` (N, 3), ``opacity_logits`` (N,), ``rgb`` (N, 3) in [0, 1]
    (``sigmoid(colors)`` of a :class:`~radar4dgs.model.gaussians.GaussianSet`). numpy arrays or
    torch tensors (any device; detached and copied to the CPU). ``sh_degree`` in 0..3 sets the
    number of (zero) ``f_rest`` properties. The file is written to a temporary name and renamed.

    Raises ValueError on a wrong shape, NaN/inf, rgb outside [0, 1], a zero quaternion or a bad
    ``sh_degree``; TypeError on a non-numeric input.
    """
    if isinstance(sh_degree, bool) or not isinstance(sh_degree, (int, np.integer)) \
            or not 0 <= sh_degree <= MAX_SH_DEGREE:
        raise ValueError(f"sh_degree must be an integer in 0..{MAX_SH_DEGREE}, got {sh_degree!r}")
    sh_degree = int(sh_degree)
    means = _to_numpy("means", means)
    if means.ndim != 2:
        raise ValueError(f"means has shape {means.shape}, expected (N, 3)")
    n = means.shape[0]
    arrays = {"means": means, "quats": _to_numpy("quats", quats),
              "log_scales": _to_numpy("log_scales", log_scales),
              "opacity_logits": _to_numpy("opacity_logits", opacity_logits),
              "rgb": _to_numpy("rgb", rgb)}
    shapes = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,),
              "rgb": (n, 3)}
    for name, shape in shapes.items():
        _check(name, arrays[name], shape)
    rgb = arrays["rgb"]
    # A colour outside [0, 1] almost always means logits or 0..255 values were passed by mistake.
    if n and (rgb.min() < 0.0 or rgb.max() > 1.0):
        raise ValueError(f"rgb must lie in [0, 1] (pass sigmoid(colors), not the logits or 0..255 "
                         f"values); got range [{rgb.min():.4g}, {rgb.max():.4g}]")
    norms = np.linalg.norm(arrays["quats"], axis=1)
    if n and not (norms > 0).all():
        first = int(np.nonzero(~(norms > 0))[0][0])
        raise ValueError(f"quats has {int((~(norms > 0)).sum())} zero quaternion(s) "
                         f"(first at index {first}); a rotation needs a non-zero quaternion")

    # float64 inputs beyond float32's range would become inf on disk: refuse instead.
    limit = float(np.finfo(np.float32).max)
    for name, array in arrays.items():
        if n and np.abs(array).max() > limit:
            raise ValueError(f"{name} has values that overflow float32 (|value| > {limit:.3g})")

    names = property_names(sh_degree)
    header = ("ply\nformat binary_little_endian 1.0\n"
              "comment radar4dgs 3D Gaussian splats (INRIA 3DGS layout)\n"
              f"element vertex {n}\n"
              + "".join(f"property float {name}\n" for name in names)
              + "end_header\n").encode("ascii")
    # Rows are filled straight into the output buffer, so a million Gaussians (~250 MB at degree
    # 3) take the file's size in memory once rather than two or three times.
    buffer = bytearray(len(header) + n * len(names) * 4)
    buffer[:len(header)] = header
    rows = np.frombuffer(buffer, dtype="<f4", offset=len(header)).reshape(n, len(names))
    k_rest = num_rest_coefficients(sh_degree)
    rows[:, 0:3] = arrays["means"]
    rows[:, 3:6] = 0.0
    rows[:, 6:9] = (rgb - 0.5) / SH_C0
    rows[:, 9:9 + k_rest] = 0.0
    tail = 9 + k_rest
    rows[:, tail] = arrays["opacity_logits"]
    rows[:, tail + 1:tail + 4] = arrays["log_scales"]
    rows[:, tail + 4:tail + 8] = arrays["quats"]
    return atomic_write_bytes(path, memoryview(buffer))


def _parse_header(path: Path, handle) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]], int]:
    """(format, [(element, count, [(property, numpy code)])], byte offset of the body)."""
    first = handle.readline()
    if first.rstrip(b"\r\n") != b"ply":
        raise ValueError(f"{path}: not a PLY file (it does not start with 'ply')")
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for _ in range(_MAX_HEADER_LINES):
        raw = handle.readline()
        if not raw:
            raise ValueError(f"{path}: PLY header has no 'end_header' line")
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError:
            raise ValueError(f"{path}: PLY header is not ASCII") from None
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            return fmt or "", elements, handle.tell()
        if words[0] == "format":
            if len(words) != 3:
                raise ValueError(f"{path}: malformed PLY line {line!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ValueError(f"{path}: malformed PLY line {line!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise ValueError(f"{path}: PLY property before any element: {line!r}")
            if len(words) >= 2 and words[1] == "list":
                elements[-1][2].append((words[-1], "list"))
                continue
            if len(words) != 3 or words[1] not in _PLY_TYPES:
                raise ValueError(f"{path}: unsupported PLY property line {line!r}")
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        else:
            raise ValueError(f"{path}: unexpected PLY header line {line!r}")
    raise ValueError(f"{path}: PLY header longer than {_MAX_HEADER_LINES} lines")


def read_gaussians_ply(path: str | os.PathLike) -> dict[str, Any]:
    """Read a standard 3DGS ``.ply`` (as :func:`write_gaussians_ply` writes, or another tool).

    Property order and types come from the header (any PLY scalar type; binary little- or
    big-endian). Returns float32 arrays: ``means`` (N, 3), ``normals`` (N, 3) (zeros where the file
    has none), ``f_dc`` (N, 3), ``f_rest`` (N, 3, K) channel-major (K = 0 at degree 0),
    ``opacity_logits`` (N,), ``log_scales`` (N, 3), ``quats`` (N, 4) wxyz as stored, ``rgb`` (N, 3)
    ``= 0.5 + C0 * f_dc`` (not clipped); plus ``sh_degree`` (int) and ``properties`` (the header's
    property names, in order).

    Raises ValueError naming the file on a missing property, a non-3DGS ``f_rest`` count, an ASCII
    or truncated file, or a malformed header.
    """
    path = Path(path)
    with open(path, "rb") as handle:
        fmt, elements, offset = _parse_header(path, handle)
        if fmt == "binary_little_endian":
            order = "<"
        elif fmt == "binary_big_endian":
            order = ">"
        else:
            raise ValueError(f"{path}: PLY format {fmt or '(none)'!r} is not supported; "
                             "expected binary_little_endian (or binary_big_endian)")
        if not elements or elements[0][0] != "vertex":
            raise ValueError(f"{path}: the first PLY element must be 'vertex', got "
                             f"{[e[0] for e in elements]}")
        _, n, props = elements[0]
        lists = [name for name, code in props if code == "list"]
        if lists:
            raise ValueError(f"{path}: list properties on vertices are not supported: {lists}")
        names = [name for name, _ in props]
        if len(set(names)) != len(names):
            raise ValueError(f"{path}: duplicate vertex property names in the header")
        dtype = np.dtype([(name, order + code) for name, code in props])
        body = handle.read(n * dtype.itemsize)
        if len(body) != n * dtype.itemsize:
            raise ValueError(f"{path}: truncated: the header declares {n} vertices "
                             f"({n * dtype.itemsize} bytes) but only {len(body)} bytes follow")
        # Trailing bytes are only legitimate as the data of further declared elements.
        if len(elements) == 1 and handle.read(1):
            raise ValueError(f"{path}: unexpected bytes after the {n} vertices")
    data = np.frombuffer(body, dtype=dtype, count=n)

    required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    missing = [name for name in required if name not in dtype.names]
    if missing:
        raise ValueError(f"{path}: missing vertex properties {missing}; a 3DGS .ply needs "
                         f"{required} (and optionally nx ny nz, f_rest_*)")
    k_rest = sum(1 for name in names if name.startswith("f_rest_"))
    degree = next((d for d in range(MAX_SH_DEGREE + 2) if num_rest_coefficients(d) == k_rest), None)
    if degree is None:
        raise ValueError(f"{path}: {k_rest} f_rest properties is not 3 * ((deg + 1)^2 - 1) for any "
                         f"SH degree 0..{MAX_SH_DEGREE + 1}")
    rest_missing = [f"f_rest_{i}" for i in range(k_rest) if f"f_rest_{i}" not in dtype.names]
    if rest_missing:
        raise ValueError(f"{path}: missing vertex properties {rest_missing[:5]} (f_rest_* must be "
                         f"numbered 0..{k_rest - 1})")

    def stack(keys: list[str]) -> np.ndarray:
        if not keys:
            return np.zeros((n, 0), dtype=np.float32)
        return np.stack([data[k].astype(np.float32) for k in keys], axis=1)

    normals = (stack(["nx", "ny", "nz"]) if all(k in dtype.names for k in ("nx", "ny", "nz"))
               else np.zeros((n, 3), dtype=np.float32))
    f_dc = stack(["f_dc_0", "f_dc_1", "f_dc_2"])
    per_channel = k_rest // 3
    return {
        "means": stack(["x", "y", "z"]),
        "normals": normals,
        "f_dc": f_dc,
        "f_rest": stack([f"f_rest_{i}" for i in range(k_rest)]).reshape(n, 3, per_channel),
        "opacity_logits": data["opacity"].astype(np.float32),
        "log_scales": stack(["scale_0", "scale_1", "scale_2"]),
        "quats": stack(["rot_0", "rot_1", "rot_2", "rot_3"]),
        "rgb": (np.float32(0.5) + np.float32(SH_C0) * f_dc).astype(np.float32),
        "sh_degree": degree,
        "properties": names,
    }
