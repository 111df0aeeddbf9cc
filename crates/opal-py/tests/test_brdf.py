"""opal.brdf: check, fit_norm and models against the CLI's --json output, bad input."""

import json
import subprocess

import numpy as np
import pytest

import opal


def cli_json(cli, args):
    r = subprocess.run([cli, "brdf", *args, "--json", "--quiet"], capture_output=True, text=True)
    assert r.returncode in (0, 1), r.stderr
    return json.loads(r.stdout)


def test_models():
    ms = opal.brdf.models()
    names = [m.name for m in ms]
    assert "pow16-norm" in names and len(set(names)) == len(names)
    assert all(len(m.default_range) == 2 for m in ms)


def test_check_equals_cli(cli):
    r = opal.brdf.check("pow16-norm", n=(1, 1000), points=20, mc_samples=20_000)
    ref = cli_json(cli, ["check", "--model", "pow16-norm", "--param", "n=1:1000", "--points", "20", "--mc-samples", "20000"])
    plain = {k: v for k, v in r.items() if k != "curve"}
    assert plain == {k: v for k, v in ref.items() if k != "curve"}
    assert isinstance(r.curve["param"], np.ndarray)
    assert np.array_equal(r.curve["max_reflectance"], [p["max_reflectance"] for p in ref["curve"]])
    assert r.energy_conserving == (r.max_reflectance <= 1 + r.tolerance)


def test_check_several_models_and_options(cli, tmp_path):
    plot = tmp_path / "r.png"
    rs = opal.brdf.check(["pow16", "pow16-norm"], points=12, incidence_deg=(0, 60), mc_samples=5000, plot=str(plot))
    assert isinstance(rs, list) and [r.model for r in rs] == ["pow16", "pow16-norm"]
    assert plot.stat().st_size > 1000
    one = opal.brdf.check("pow16", norm="(n+A)/B", A=6, B=24.55, points=12, incidence_deg=30, mc_samples=5000)
    ref = cli_json(cli, ["check", "--model", "pow16", "--norm", "(n+A)/B", "--points", "12", "--incidence-deg", "30", "--mc-samples", "5000"])
    assert one.max_reflectance == ref["max_reflectance"]


def test_fit_norm_equals_cli(cli):
    r = opal.brdf.fit_norm("pow16", form="(n+A)/B", n=(1, 1000))
    ref = cli_json(cli, ["fit-norm", "--model", "pow16", "--form", "(n+A)/B", "--param", "n=1:1000"])
    assert dict(r) == ref
    assert r.bounded["max_reflectance"] <= 1 + 1e-6


def test_bad_input(cli):
    cases = [
        (lambda: opal.brdf.check("no-such-model"), ["check", "--model", "no-such-model"]),
        (lambda: opal.brdf.check("pow16-norm", n=(10, 1)), ["check", "--model", "pow16-norm", "--param", "n=10:1"]),
        (lambda: opal.brdf.check("pow16-norm", m=(1, 10)), ["check", "--model", "pow16-norm", "--param", "m=1:10"]),
        (lambda: opal.brdf.check("pow16-norm", incidence_deg=(0, 95)), ["check", "--model", "pow16-norm", "--incidence-deg", "0:95"]),
        (lambda: opal.brdf.fit_norm("pow16", form="(n+"), ["fit-norm", "--model", "pow16", "--form", "(n+"]),
    ]
    for call, args in cases:
        with pytest.raises(opal.OpalError) as e:
            call()
        r = subprocess.run([cli, "brdf", *args], capture_output=True, text=True)
        assert r.returncode == 2
        assert f"error: {e.value}" in r.stderr
    with pytest.raises(TypeError):
        opal.brdf.check("pow16", n=(1, 2), m=(1, 2))
