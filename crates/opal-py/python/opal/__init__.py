"""Opal from Python: numpy in, numpy out.

Opal recovers optical properties of real surfaces by physically based light simulation. This
package calls the same Rust library functions as the ``opal`` command line, so results are the
same bit for bit for the same seed, and errors carry the same messages.

Quick start::

    import opal
    scene = opal.load_scene("scene.xml")
    img = scene.render(spp=16, seed=5)          # float32 array (H, W, 3), linear RGB
    opal.write_exr("out.exr", img)

Modules and functions:

* :func:`load_scene`, :class:`Scene` (``Scene.render``): path tracer (``opal render``)
* :func:`read_exr`, :func:`write_exr`: float32 RGB images
* :mod:`opal.gonio` (``gonio.simulate``): virtual goniophotometer (``opal gonio simulate``)
* :func:`fit_ndf`: fit the micro-facet NDF to measured curves (``opal fit-ndf``)
* :func:`delight`: albedo textures from multi-view HDR photos (``opal delight``)
* :mod:`opal.brdf` (``brdf.check``, ``brdf.fit_norm``, ``brdf.models``): energy checks (``opal brdf``)

Long calls release the GIL, stop on Ctrl-C (``KeyboardInterrupt``) and take an optional
``progress(stage, done, total)`` callback. Errors raise :class:`OpalError` (a ``ValueError``).
"""

from __future__ import annotations

import os
from typing import Any, Callable, Dict, Mapping, Optional, Sequence, Union

import numpy as np

from . import _native
from ._native import OpalError
from ._common import Result, read_csv_columns, run_command
from . import brdf, gonio

__all__ = [
    "OpalError",
    "Scene",
    "Result",
    "load_scene",
    "read_exr",
    "write_exr",
    "fit_ndf",
    "delight",
    "gonio",
    "brdf",
    "__version__",
]

__version__: str = _native.__version__

PathLike = Union[str, "os.PathLike[str]"]
Progress = Optional[Callable[[str, int, Optional[int]], Any]]


def _image(data: bytearray, height: int, width: int) -> np.ndarray:
    return np.frombuffer(data, dtype="<f4").reshape(height, width, 3)


def _param_text(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


class Scene:
    """A Mitsuba 3 XML scene, loaded and built (see :func:`load_scene`)."""

    def __init__(self, native: "_native.Scene") -> None:
        self._native = native

    @property
    def path(self) -> str:
        """The scene file."""
        return os.fspath(self._native.path)

    @property
    def sensors(self) -> list:
        """The sensors as ``(id, width, height)`` tuples, in file order."""
        return list(self._native.sensors)

    def render(
        self,
        spp: Optional[int] = None,
        max_depth: Optional[int] = None,
        sensor: Union[int, str] = 0,
        seed: int = 0,
        threads: Optional[int] = None,
        progress: Progress = None,
        report: bool = False,
    ):
        """Path-traces a sensor, like ``opal render scene.xml --spp SPP --seed SEED``.

        Args:
            spp: samples per pixel (default: the sensor's sampler, else 64); at least 1.
            max_depth: maximum path depth, Mitsuba's meaning (default: the scene's integrator;
                -1 = unbounded).
            sensor: index (0-based) or ``id`` of the sensor.
            seed: seed of the random numbers; the image depends only on it, never on ``threads``.
            threads: worker threads (default: all cores).
            progress: optional ``progress(stage, done_rows, total_rows)``, called about every
                0.1 s and once at the end; an exception it raises stops the render.
            report: also return the run's report (dict: spp, seconds, samples per second, ...).

        Returns:
            float32 array ``(H, W, 3)`` of linear RGB (row 0 at the top); with ``report=True``
            a tuple ``(image, report)``. The same bits as the CLI's EXR for the same seed.

        Raises:
            OpalError: bad arguments (e.g. ``spp=0``, unknown sensor), a sensor that sees nothing.
            KeyboardInterrupt: Ctrl-C; the render stops at the next rows.
        """
        if spp is not None and (isinstance(spp, bool) or int(spp) != spp or spp < 0):
            raise OpalError(f"--spp must be a positive integer, got {spp!r}")
        data, h, w, rep = self._native.render(
            spp=None if spp is None else int(spp),
            max_depth=max_depth,
            sensor=str(sensor),
            seed=int(seed),
            threads=threads,
            progress=progress,
        )
        img = _image(data, h, w)
        if report:
            import json

            return img, json.loads(rep)
        return img

    def __repr__(self) -> str:
        return repr(self._native)


def load_scene(path: PathLike, **params: Any) -> Scene:
    """Loads and builds a Mitsuba 3 XML scene.

    Args:
        path: the scene file.
        **params: values of the scene's ``$name`` parameters (like ``opal render -D name=value``);
            booleans become ``true``/``false``, other values their ``str``.

    Raises:
        OpalError: unreadable or invalid scene (the CLI's message, with file and line).
    """
    defines = [(k, _param_text(v)) for k, v in params.items()]
    return Scene(_native.load_scene(os.fspath(path), defines))


def read_exr(path: PathLike) -> np.ndarray:
    """Reads an OpenEXR image (also PNG / HDR) as stored: float32 ``(H, W, 3)``, row 0 at the top.

    Raises:
        OpalError: missing or unreadable file.
    """
    data, h, w = _native.read_exr(os.fspath(path))
    return _image(data, h, w)


def write_exr(path: PathLike, image: Any) -> None:
    """Writes a float32 linear-RGB OpenEXR file, the way ``opal render`` writes its output.

    Args:
        path: output file (written atomically: complete or not at all).
        image: array-like ``(H, W, 3)`` (or ``(H, W)``: grey, repeated in R, G, B); converted
            to float32.

    Raises:
        ValueError: wrong shape; OpalError: the file cannot be written.
    """
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"write_exr: expected an (H, W, 3) or (H, W) array, got shape {a.shape}")
    if a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"write_exr: the image is empty (shape {a.shape})")
    a = np.ascontiguousarray(a, dtype="<f4")
    _native.write_exr(os.fspath(path), a.tobytes(), a.shape[0], a.shape[1])


def _measured_files(measured: Any, tmp: str) -> list:
    """Measured curves as file paths: paths stay, a mapping of columns becomes a CSV."""
    if isinstance(measured, (str, os.PathLike)):
        return [os.fspath(measured)]
    if isinstance(measured, Mapping) or hasattr(measured, "columns"):
        cols = {k: np.asarray(measured[k]) for k in ("incidence_deg", "side", "detector_deg", "value")}
        names = ["incidence_deg", "side", "detector_deg", "value"]
        for extra in ("value_stderr", "detector_azimuth_deg"):
            if extra in measured:
                cols[extra] = np.asarray(measured[extra])
                names.append(extra)
        n = len(cols["value"])
        if any(len(c) != n for c in cols.values()):
            raise ValueError("fit_ndf: the measured columns have different lengths")
        p = os.path.join(tmp, "measured.csv")
        with open(p, "w") as f:
            f.write(",".join(names) + "\n")
            for i in range(n):
                f.write(",".join(_csv_cell(cols[k][i]) for k in names) + "\n")
        return [p]
    files = [os.fspath(m) for m in measured]
    if not files:
        raise ValueError("fit_ndf: no measured file given")
    return files


def _csv_cell(v: Any) -> str:
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return str(v)


def _flags(options: Mapping[str, Any], positional: Sequence[str] = ()) -> list:
    """Keyword options as command-line flags: ``hybrid_nodes=4`` → ``--hybrid-nodes=4``;
    ``True`` → the bare flag; ``False``/``None`` → nothing; lists repeat or join by commas."""
    argv = list(positional)
    for k, v in options.items():
        if v is None or v is False:
            continue
        flag = "--" + (k if k in ("A", "B") else k.replace("_", "-"))
        if v is True:
            argv.append(flag)
        elif isinstance(v, (list, tuple)):
            argv.append(f"{flag}=" + ",".join(_flag_value(x) for x in v))
        else:
            # `--flag=value`: a negative number is a value, not a flag
            argv.append(f"{flag}={_flag_value(v)}")
    return argv


def _flag_value(v: Any) -> str:
    if isinstance(v, (str, os.PathLike)):
        return os.fspath(v)
    if isinstance(v, float):
        return repr(v)
    return str(v)


def fit_ndf(
    measured: Any,
    output: Optional[PathLike] = None,
    threads: Optional[int] = None,
    progress: Progress = None,
    **options: Any,
) -> Result:
    """Fits the micro-facet NDF of a plate's rough face to measured curves (``opal fit-ndf``).

    Args:
        measured: a CSV or Zemax ``.BSDF`` path, a list of them, or columns (a dict or
            DataFrame with ``incidence_deg, side, detector_deg, value[, value_stderr]``, e.g.
            :func:`opal.gonio.simulate`'s curves).
        output: folder for the CLI's outputs (fit.json, curves, BSDF tables, plots); default a
            temporary folder that is removed afterwards.
        threads: worker threads (default: all cores); results do not depend on it.
        progress: optional ``progress(stage, done, total)`` callback.
        **options: the CLI's options by name, e.g. ``family="ggx"``, ``entry="rough"``,
            ``photons=30000``, ``seed=1``, ``shift=True``, ``plate="plate.toml"``,
            ``no_render=True`` (skip the chessboard render).

    Returns:
        :class:`Result`: the fields of fit.json as attributes/keys (``family``, ``alpha``,
        ``rms``, ``converged``, ``candidates``, …) plus ``curves`` (measured and fitted curves
        as arrays: ``incidence_deg, side, detector_deg, measured, measured_stderr, fitted,
        fitted_stderr``) and ``ndf`` (``theta_m_deg, D, D_cos``).

    Raises:
        OpalError: bad input (same message as the CLI). A fit that did not converge is not an
        error: check ``result.converged``.
    """
    import tempfile

    with tempfile.TemporaryDirectory(prefix="opal-fit-") as tmp:
        files = _measured_files(measured, tmp)
        out = os.fspath(output) if output is not None else os.path.join(tmp, "out")
        res = run_command(["fit-ndf", *files, "-o", out, *_flags(options)], threads, progress)
        res["curves"] = read_csv_columns(os.path.join(out, "fitted_curves.csv"))
        res["ndf"] = read_csv_columns(os.path.join(out, "ndf.csv"))
        res["output"] = os.fspath(output) if output is not None else None
        return Result(res)


def delight(
    scene: Union[PathLike, Scene],
    views: PathLike,
    output: Optional[PathLike] = None,
    threads: Optional[int] = None,
    progress: Progress = None,
    **options: Any,
) -> Result:
    """Recovers diffuse albedo textures from multi-view HDR photos (``opal delight``).

    Args:
        scene: the Mitsuba 3 XML scene (a path, or a :class:`Scene` loaded from one).
        views: NeRF-style transforms.json or a COLMAP text model folder.
        output: folder for the CLI's outputs (textures, meshes, scene.xml, report); default a
            temporary folder removed afterwards (then only the returned arrays remain).
        threads: worker threads (default: all cores).
        progress: optional ``progress(stage, done, total)`` callback.
        **options: the CLI's options by name, e.g. ``iterations=3``, ``resolution=256``,
            ``light_paths=200000``, ``objects=["floor", "box"]``, ``rerender_spp=0``, ``seed=1``.

    Returns:
        :class:`Result`: report.json's fields plus ``albedo``: a dict object id → float32
        ``(H, W, 3)`` texture, and ``log`` (the lines the CLI prints).

    Raises:
        OpalError: bad input; KeyboardInterrupt: Ctrl-C (finished iterations are kept in
        ``output/checkpoint``; call again with ``resume=True``).
    """
    import tempfile

    scene_path = scene.path if isinstance(scene, Scene) else os.fspath(scene)
    with tempfile.TemporaryDirectory(prefix="opal-delight-") as tmp:
        out = os.fspath(output) if output is not None else os.path.join(tmp, "out")
        argv = ["delight", "--scene", scene_path, "--views", os.fspath(views), "-o", out, *_flags(options)]
        res = run_command(argv, threads, progress)
        albedo: Dict[str, np.ndarray] = {}
        for o in res.get("objects", []):
            if o.get("texture"):
                albedo[o["id"]] = read_exr(os.path.join(out, o["texture"])).copy()
        res["albedo"] = albedo
        res["output"] = os.fspath(output) if output is not None else None
        return Result(res)
