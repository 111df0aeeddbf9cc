"""Virtual goniophotometer (``opal gonio simulate``): a plate with polished/rough faces in a
beam, detectors on an angular grid. See docs/gonio.md for the plate file and the quantities."""

from __future__ import annotations

import os
from typing import Any, Callable, Mapping, Optional, Union

from ._common import Result, columns, run_command

__all__ = ["simulate", "plate_toml"]


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(int(v))


def plate_toml(plate: Mapping[str, Any]) -> str:
    """PLATE.toml text of a nested dict, e.g. ``{"beam": {"incidences_deg": [0, 30]},
    "detectors": {"layout": "hemisphere"}, "plate": {"back": {"ndf": "ggx:0.2"}}}``."""
    lines = []

    def table(name: str, d: Mapping[str, Any]) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, Mapping)}
        if name:
            lines.append(f"[{name}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {_toml_value(v)}")
        for k, v in d.items():
            if isinstance(v, Mapping):
                table(f"{name}.{k}" if name else k, v)

    table("", plate)
    return "\n".join(lines) + "\n"


def simulate(
    plate: Optional[Union[str, "os.PathLike[str]", Mapping[str, Any]]] = None,
    ndf: Optional[str] = None,
    photons: Optional[int] = None,
    seed: Optional[int] = None,
    entry: Optional[str] = None,
    layout: Optional[str] = None,
    threads: Optional[int] = None,
    progress: Optional[Callable[[str, int, Optional[int]], Any]] = None,
    **options: Any,
) -> Result:
    """Simulates a plate in the virtual goniophotometer, like ``opal gonio simulate``.

    Args:
        plate: PLATE.toml with sample, beam and detectors (layout, incidences), or the same
            as a nested dict (see :func:`plate_toml`); defaults apply without it (docs/gonio.md).
        ndf: NDF of the rough face, ``"ggx:0.15"``, ``"beckmann:0.25"``, ``"student:0.2:3"``.
        photons: photons per incidence angle.
        seed: random seed; the curves depend on it, never on ``threads``.
        entry: the lit face, ``"smooth"`` or ``"rough"``.
        layout: detector layout, ``"plane"`` or ``"hemisphere"`` (sets the plate's
            ``[detectors] layout``; with a dict or no ``plate`` only).
        threads: worker threads (default: all cores).
        progress: optional ``progress(stage, done_batches, total_batches)`` callback.
        **options: the CLI's other flags by name: ``ior``, ``thickness_mm``,
            ``divergence_deg``, ``detector_radius_deg``, ``scattering``, ``plot`` (a PNG/SVG path).

    Returns:
        :class:`opal.Result` with ``curves`` (columns as numpy arrays, one row per incidence and
        detector: ``incidence_deg, side, detector_deg, value, value_stderr, bsdf, n_hits``, and
        ``detector_azimuth_deg`` with the hemisphere layout; ``pandas.DataFrame(r.curves)``
        makes a table; the numbers of the CLI's CSV, which prints 9 significant digits) and
        ``totals`` (R, T, lost per incidence, as ``--json`` prints).

    Raises:
        OpalError: bad input (same message as the CLI); KeyboardInterrupt: Ctrl-C.
    """
    import tempfile

    from . import _flags

    if layout is not None:
        if plate is not None and not isinstance(plate, Mapping):
            raise ValueError("gonio.simulate: give layout in the plate file, or plate as a dict")
        plate = dict(plate or {})
        plate["detectors"] = dict(plate.get("detectors", {}), layout=layout)
    with tempfile.TemporaryDirectory(prefix="opal-gonio-") as tmp:
        if isinstance(plate, Mapping):
            path = os.path.join(tmp, "plate.toml")
            with open(path, "w") as f:
                f.write(plate_toml(plate))
            plate = path
        return _simulate(plate, ndf, photons, seed, entry, threads, progress, options, _flags)


def _simulate(plate, ndf, photons, seed, entry, threads, progress, options, _flags) -> Result:
    argv = ["gonio", "simulate"]
    if plate is not None:
        argv.append(os.fspath(plate))
    # the result is returned, not written: -o is required by the parser only
    argv += ["-o", os.devnull]
    argv += _flags(dict(ndf=ndf, photons=photons, seed=seed, entry=entry, **options))
    res = run_command(argv, threads, progress)
    return Result(curves=columns(res["curves"]), totals=res["totals"])
