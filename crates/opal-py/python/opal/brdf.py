"""Energy conservation and reciprocity of BRDF lobes, normalisation fitting (``opal brdf``,
method B; docs/brdf.md)."""

from __future__ import annotations

from typing import Any, List, Optional, Sequence, Tuple, Union

import numpy as np

from ._common import Result, run_command

__all__ = ["check", "fit_norm", "models"]

Range = Union[Tuple[float, float], Sequence[float], str]


def _range(name: str, r: Optional[Range], flag: str) -> Optional[str]:
    if r is None:
        return None
    if isinstance(r, str):
        return r
    lo, hi = r
    return f"{name}={lo!r}:{hi!r}" if name else f"{lo!r}:{hi!r}"


def _param(kw: dict) -> Optional[str]:
    """``n=(1, 1000)`` (any parameter name) → ``--param n=1:1000``."""
    extra = [k for k in kw]
    if len(extra) > 1:
        raise TypeError(f"at most one parameter range, got {extra}")
    if not extra:
        return None
    k = extra[0]
    return _range(k, kw[k], "--param")


def check(
    model: Union[str, Sequence[str]],
    norm: Optional[str] = None,
    A: float = 6.0,
    B: float = 24.55,
    incidence_deg: Range = (0.0, 89.0),
    tolerance: float = 1e-4,
    points: int = 80,
    incidence_points: int = 10,
    mc_samples: int = 200_000,
    seed: int = 1,
    plot: Optional[str] = None,
    threads: Optional[int] = None,
    progress: Any = None,
    **param: Range,
) -> Union[Result, List[Result]]:
    """Directional–hemispherical reflectance of a lobe over its parameter (``opal brdf check``).

    Example: ``opal.brdf.check("pow16-norm", n=(1, 1000))``.

    Args:
        model: a model name (see :func:`models`) or a list of them.
        norm: normalisation expression in n, A, B replacing the model's own, e.g. ``"(n+A)/B"``.
        A, B: constants of ``norm``.
        incidence_deg: ``(lo, hi)`` incidence range in degrees within [0, 90), or one angle.
        tolerance: R may exceed 1 by this much before it is a violation.
        points, incidence_points: grid sizes (refined around maxima and violation edges).
        mc_samples, seed: the Monte Carlo cross-check.
        plot: also write the CLI's plot of R (PNG or SVG path).
        **param: the parameter range, e.g. ``n=(1, 1000)`` (default: the model's own).

    Returns:
        :class:`opal.Result` (a list for several models): the fields of ``--json``
        (``max_reflectance``, ``energy_conserving``, ``violations``, ``reciprocity_error``, …)
        with ``curve`` as numpy columns.

    Raises:
        OpalError: unknown model, bad range (the CLI's message).
    """
    models_ = [model] if isinstance(model, str) else list(model)
    if not models_:
        raise ValueError("brdf.check: no model given")
    argv = ["brdf", "check"]
    for m in models_:
        argv.append(f"--model={m}")
    p = _param(param)
    if p is not None:
        argv.append(f"--param={p}")
    if norm is not None:
        argv.append(f"--norm={norm}")
    argv += [f"--A={float(A)!r}", f"--B={float(B)!r}", f"--incidence-deg={_inc(incidence_deg)}"]
    argv += [f"--tolerance={float(tolerance)!r}", f"--points={points}"]
    argv += [f"--incidence-points={incidence_points}", f"--mc-samples={mc_samples}", f"--seed={seed}"]
    if plot is not None:
        argv.append(f"--plot={plot}")
    reports = [_with_curve(r) for r in run_command(argv, threads, progress)]
    return reports[0] if isinstance(model, str) else reports


def _inc(r: Range) -> str:
    if isinstance(r, (int, float)):
        return repr(float(r))
    return _range("", r, "--incidence-deg") or ""


def _with_curve(r: dict) -> Result:
    res = Result(r)
    curve = r.get("curve")
    if isinstance(curve, list) and curve and isinstance(curve[0], dict):
        res["curve"] = {k: np.asarray([p[k] for p in curve], dtype=np.float64) for k in curve[0]}
    return res


def fit_norm(
    model: str,
    form: str = "(n+A)/B",
    A: float = 6.0,
    B: float = 24.55,
    incidence_deg: Range = (0.0, 89.0),
    threads: Optional[int] = None,
    progress: Any = None,
    **param: Range,
) -> Result:
    """Fits the constants of a normalisation factor (``opal brdf fit-norm``).

    Example: ``opal.brdf.fit_norm("pow16", form="(n+A)/B", n=(1, 1000))``.

    Args:
        model: model whose raw lobe is normalised.
        form: normalisation form in n, A, B.
        A, B: starting values.
        incidence_deg: R₀(n) is the maximum over this range.
        **param: the exponent range, e.g. ``n=(1, 1000)``.

    Returns:
        :class:`opal.Result` with the ``--json`` fields: ``least_squares`` and ``bounded``
        (each ``a``, ``b``, ``max_reflectance``, ``rms_residual``, …), ``range``, ``samples``.
    """
    argv = ["brdf", "fit-norm", f"--model={model}", f"--form={form}"]
    p = _param(param)
    if p is not None:
        argv.append(f"--param={p}")
    argv += [f"--A={float(A)!r}", f"--B={float(B)!r}", f"--incidence-deg={_inc(incidence_deg)}"]
    return Result(run_command(argv, threads, progress))


def models() -> List[Result]:
    """The BRDF model names with their parameter and default range (``opal brdf list``)."""
    return [Result(m) for m in run_command(["brdf", "list"], None, None)]
