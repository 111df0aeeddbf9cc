"""opal.gonio.simulate: the CLI's numbers, layouts, threads, progress, bad input."""

import csv
import json
import subprocess

import numpy as np
import pytest

import opal

PLATE = {"beam": {"incidences_deg": [0, 30]}, "run": {"photons": 20000}}


@pytest.fixture(scope="module")
def plate_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("gonio") / "plate.toml"
    p.write_text(opal.gonio.plate_toml(PLATE))
    return p


def test_simulate_equals_cli_csv(plate_file, cli, tmp_path):
    r = opal.gonio.simulate(plate_file, ndf="ggx:0.15", seed=3, entry="rough")
    c = r.curves
    n = len(c["value"])
    assert n == 2 * 2 * 179  # two incidences, R and T, detectors -89..89 step 1
    assert all(len(v) == n for v in c.values())
    assert set(c["side"]) == {"R", "T"} and c["n_hits"].dtype == np.int64
    out = tmp_path / "c.csv"
    res = subprocess.run(
        [cli, "gonio", "simulate", str(plate_file), "-o", str(out), "--ndf", "ggx:0.15", "--seed", "3",
         "--entry", "rough", "--json", "--quiet"],
        check=True, capture_output=True, text=True,
    )
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == n
    for i, row in enumerate(rows):
        # the CSV prints 9 significant digits: the same digits from the same numbers
        for k in ("value", "value_stderr", "bsdf"):
            assert float(row[k]) == float(f"{c[k][i]:.8e}"), (i, k)
        assert row["side"] == c["side"][i] and int(row["n_hits"]) == c["n_hits"][i]
        assert float(row["detector_deg"]) == round(c["detector_deg"][i], 6)
    totals = json.loads(res.stdout)
    for a, b in zip(totals["incidences"], r.totals["incidences"]):
        assert a["R"] == b["R"] and a["T"] == b["T"] and a["lost"] == b["lost"]


def test_threads_do_not_matter_and_seed_does():
    a = opal.gonio.simulate(PLATE, ndf="beckmann:0.2", seed=1, threads=1)
    b = opal.gonio.simulate(PLATE, ndf="beckmann:0.2", seed=1, threads=2)
    c = opal.gonio.simulate(PLATE, ndf="beckmann:0.2", seed=2, threads=2)
    assert np.array_equal(a.curves["value"], b.curves["value"])
    assert not np.array_equal(a.curves["value"], c.curves["value"])
    R, T = a.totals["incidences"][0]["R"], a.totals["incidences"][0]["T"]
    assert 0 < R < 1 and 0 < T < 1


def test_hemisphere_layout_and_options(tmp_path):
    plot = tmp_path / "p.png"
    r = opal.gonio.simulate(
        {"beam": {"incidences_deg": [20]}, "detectors": {"polar_step_deg": 15, "azimuth_step_deg": 45}},
        layout="hemisphere", ndf="ggx:0.3", photons=5000, ior=1.6, thickness_mm=1.0, plot=str(plot),
    )
    az = r.curves["detector_azimuth_deg"]
    assert len(set(np.round(az, 6))) > 2
    assert plot.stat().st_size > 1000


def test_progress():
    calls = []
    opal.gonio.simulate(PLATE, ndf="ggx:0.1", photons=20000, progress=lambda *a: calls.append(a))
    stage, done, total = calls[-1]
    assert stage == "gonio" and done == total and total > 0


def test_bad_input(cli, tmp_path):
    cases = [
        (dict(ndf="ggx:-1"), ["--ndf", "ggx:-1"]),
        (dict(ndf="lorentz:0.1"), ["--ndf", "lorentz:0.1"]),
        (dict(entry="sideways"), ["--entry", "sideways"]),
        (dict(photons=0), ["--photons", "0"]),
        (dict(ior=-1.0), ["--ior=-1.0"]),
    ]
    for kw, args in cases:
        with pytest.raises(opal.OpalError) as e:
            opal.gonio.simulate(PLATE, **kw)
        r = subprocess.run([cli, "gonio", "simulate", "-o", str(tmp_path / "x.csv"), *args], capture_output=True, text=True)
        assert r.returncode == 2, r.stderr
        assert f"error: {e.value}" in r.stderr
    with pytest.raises(opal.OpalError, match="unexpected argument '--no-such-flag'"):
        opal.gonio.simulate(PLATE, no_such_flag=3)
    with pytest.raises(opal.OpalError):
        opal.gonio.simulate(tmp_path / "missing.toml")
    with pytest.raises(opal.OpalError):
        opal.gonio.simulate({"beam": {"incidences_deg": [95]}})
    with pytest.raises(ValueError, match="layout"):
        opal.gonio.simulate(tmp_path / "p.toml", layout="plane")


def test_ctrl_c_interrupts_simulation():
    import _thread
    import threading
    import time

    timer = threading.Timer(0.5, _thread.interrupt_main)
    t0 = time.time()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            opal.gonio.simulate(PLATE, ndf="ggx:0.15", photons=200_000_000)
    finally:
        timer.cancel()
    assert time.time() - t0 < 60
    # the next call runs normally
    assert len(opal.gonio.simulate(PLATE, ndf="ggx:0.15", photons=2000).curves["value"]) > 0
