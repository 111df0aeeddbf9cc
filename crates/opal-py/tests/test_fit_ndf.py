"""opal.fit_ndf: the CLI's fit.json for the same inputs, columns as input, outputs, bad input."""

import json
import subprocess

import numpy as np
import pytest

import opal

PLATE = {"beam": {"incidences_deg": [0, 30]}, "detectors": {"angles_deg": list(range(-60, 61, 2))}}
FIT = dict(entry="rough", family="ggx", photons=20000, no_render=True)


@pytest.fixture(scope="module")
def measured(tmp_path_factory, cli):
    """Curves of a GGX α = 0.15 plate, written by the CLI."""
    d = tmp_path_factory.mktemp("fit")
    plate = d / "plate.toml"
    plate.write_text(opal.gonio.plate_toml(PLATE))
    csv = d / "measured.csv"
    subprocess.run(
        [cli, "gonio", "simulate", str(plate), "-o", str(csv), "--ndf", "ggx:0.15", "--entry", "rough",
         "--photons", "100000", "--seed", "7", "--quiet"],
        check=True,
    )
    return plate, csv


def test_fit_equals_cli(measured, cli, tmp_path):
    plate, csv = measured
    r = opal.fit_ndf(csv, plate=plate, output=tmp_path / "py", **FIT)
    subprocess.run(
        [cli, "fit-ndf", str(csv), "--plate", str(plate), "-o", str(tmp_path / "cli"), "--entry", "rough",
         "--family", "ggx", "--photons", "20000", "--no-render", "--quiet"],
        check=True,
    )
    ref = json.loads((tmp_path / "cli" / "fit.json").read_text())
    mine = json.loads((tmp_path / "py" / "fit.json").read_text())
    skip = {"seconds", "measured", "face"}
    assert {k: v for k, v in ref.items() if k not in skip} == {k: v for k, v in mine.items() if k not in skip}
    for k in ("family", "alpha", "rms", "noise", "converged", "candidates", "scale"):
        assert r[k] == ref[k], k
    assert r.family == "ggx" and abs(r.alpha - 0.15) < 0.02
    # the curves and the NDF as arrays
    c = r.curves
    assert set(c) >= {"incidence_deg", "side", "detector_deg", "measured", "measured_stderr", "fitted", "fitted_stderr"}
    assert len(c["measured"]) == len(c["fitted"]) > 100
    assert r.ndf["theta_m_deg"][0] == 0 and (r.ndf["D"] >= 0).all()
    assert r.output == str(tmp_path / "py")
    assert (tmp_path / "py" / "bsdf.csv").exists()


def test_fit_from_columns(measured):
    plate, _ = measured
    sim = opal.gonio.simulate(plate, ndf="ggx:0.2", entry="rough", photons=50000, seed=2)
    r = opal.fit_ndf(sim.curves, plate=plate, **FIT)
    assert abs(r.alpha - 0.2) < 0.03 and isinstance(r.converged, bool)
    assert r.output is None and r.rms_over_noise > 0


def test_bad_input(measured, cli, tmp_path):
    plate, csv = measured
    cases = [
        (dict(family="lorentz"), ["--family", "lorentz"]),
        (dict(fit_on="X"), ["--fit-on", "X"]),
        (dict(scale="relative"), ["--scale", "relative"]),
        (dict(rel_error=-0.1), ["--rel-error=-0.1"]),
    ]
    for kw, args in cases:
        with pytest.raises(opal.OpalError) as e:
            opal.fit_ndf(csv, **kw)
        r = subprocess.run([cli, "fit-ndf", str(csv), "-o", str(tmp_path / "o"), *args], capture_output=True, text=True)
        assert r.returncode == 2, r.stderr
        assert f"error: {e.value}" in r.stderr
    with pytest.raises(opal.OpalError, match="missing.csv"):
        opal.fit_ndf(tmp_path / "missing.csv")
    with pytest.raises(ValueError):
        opal.fit_ndf({"incidence_deg": [0], "side": ["T"], "detector_deg": [0, 1], "value": [1.0]})
    with pytest.raises(ValueError):
        opal.fit_ndf([])


def test_ctrl_c_interrupts_a_fit(measured):
    """A fit of 20 M photons per simulation (minutes) stops within seconds of Ctrl-C."""
    import _thread
    import threading
    import time

    plate, csv = measured
    timer = threading.Timer(1.0, _thread.interrupt_main)
    t0 = time.time()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            opal.fit_ndf(csv, plate=plate, entry="rough", family="auto", photons=20_000_000, no_render=True)
    finally:
        timer.cancel()
    assert time.time() - t0 < 60
    # the next call runs normally
    assert opal.fit_ndf(csv, plate=plate, **FIT).family == "ggx"
