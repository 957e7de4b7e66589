"""The step contract (georef_core.steps.contract, specs.py): one declaration per step read by every layer.
Options checked with messages naming the step and option; the specs agree with the option dataclasses the
step functions take; and a toy step declared through its spec alone (tests/steps/toy_step.py, loaded as a
plug-in) shows in the CLI, the API's schema and settings checks, and runs on a real worker."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from georef_core.steps.contract import OptionError, get_spec

from .plugin_registration import plugin_registered

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PLUGIN = "tests.steps.toy_step"


def test_core_steps_declared_in_order_without_science_imports():
    code = ("import sys; from georef_core.steps.contract import all_specs; "
            "print(','.join(s.name for s in all_specs())); "
            "print(any(m in sys.modules for m in ('numpy', 'pycolmap', 'scipy', 'cv2')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True,
                         env={**os.environ, "GEOREF_STEP_PLUGINS": ""}).stdout.split()
    assert out == ["gnss,georef,dense,dtm,volumes,design,datum,exports", "False"]


def test_options_are_checked_and_named():
    g = get_spec("georef")
    assert g.validate({"camera_model": "radial", "gcp_sigma_m": [0.01, 0.03], "delay_s": 0}) == \
        {"camera_model": "radial", "gcp_sigma_m": [0.01, 0.03], "delay_s": 0.0}
    for bad, words in (({"camera_model": "pinhole"}, "georef settings: camera_model: 'pinhole' is not one of"),
                       ({"camra_model": "brown"}, "georef settings: camra_model: unknown option"),
                       ({"gcp_sigma_m": [0.01]}, "gcp_sigma_m: needs 2 numbers"),
                       ({"max_tie_points": 12.5}, "max_tie_points: 12.5 is not a whole number"),
                       ({"estimate_delay": "yes"}, "estimate_delay: 'yes' is not true or false"),
                       ({"sigma_px": -1}, "sigma_px: -1 is below the minimum")):
        with pytest.raises(OptionError, match=words):
            g.validate(bad)
    with pytest.raises(OptionError, match="gnss settings: ratio: nan is not a finite number"):
        get_spec("gnss").validate({"ratio": float("nan")})


def test_specs_agree_with_the_option_dataclasses():
    from georef_core.steps.dense import DenseOptions
    from georef_core.steps.georef_options import GeorefOptions
    from georef_core.volumes.volume import VolumeOptions

    def defaults(cls, skip=()):
        out = {}
        for f in dataclasses.fields(cls):
            if f.name in skip:
                continue
            out[f.name] = None if f.default is dataclasses.MISSING else f.default
        return out

    dense = {o.name: o.default for o in get_spec("dense").options}
    assert dense == defaults(DenseOptions)
    vol = {o.name: o.default for o in get_spec("volumes").options}
    assert defaults(VolumeOptions).items() <= vol.items()
    georef = {o.name: o.default for o in get_spec("georef").options}
    assert georef == {k: (None if isinstance(v, dict) else v)
                      for k, v in defaults(GeorefOptions, ("gnss_options", "num_threads", "reuse", "exif_time_offset_s",
                                                           "ppk_from_gnss_step")).items()}


def test_json_schema_of_a_step():
    s = get_spec("gnss").json_schema()
    assert s["additionalProperties"] is False
    assert s["properties"]["ar"]["anyOf"][0]["enum"] == ["off", "continuous", "instantaneous", "fix-and-hold"]
    assert s["properties"]["elmask"]["x-unit"] == "deg" and s["properties"]["elmask"]["default"] == 15.0
    assert s["properties"]["base_position_ecef_m"]["anyOf"][0]["minItems"] == 3


def _cli(*args, plugins=PLUGIN):
    env = {**os.environ, "GEOREF_STEP_PLUGINS": plugins, "PYTHONPATH": REPO}
    return subprocess.run([sys.executable, "-m", "georef_core.cli.main", *args], cwd=REPO, capture_output=True,
                          text=True, env=env)


def test_toy_step_in_the_cli(tmp_path):
    r = _cli("steps", "--json")
    assert r.returncode == 0, r.stderr
    names = [s["name"] for s in json.loads(r.stdout)["items"]]
    assert names == ["gnss", "georef", "dense", "dtm", "volumes", "design", "datum", "exports", "toy"]
    survey = tmp_path / "survey"
    survey.mkdir()
    (survey / "a.txt").write_text("x")
    r = _cli("step", "toy", str(survey), "--out", str(tmp_path / "out"), "--set", "repeat=2", "--crs", "EPSG:32631",
             "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == {"lines": 2, "survey_files": 1}
    assert (tmp_path / "out" / "toy" / "hello.txt").read_text().splitlines() == ["hello, EPSG:32631"] * 2 + ["a.txt"]
    r = _cli("step", "toy", str(survey), "--out", str(tmp_path / "out"), "--set", "repeat=9")
    assert r.returncode == 2 and "toy settings: repeat: 9 is above the maximum 5" in r.stderr
    assert "toy" not in _cli("steps", plugins="").stdout


@pytest.fixture
def toy_registered(monkeypatch):
    with plugin_registered(monkeypatch, PLUGIN, "toy"):
        yield


def test_toy_step_through_the_api_and_a_real_worker(tmp_path, toy_registered):
    from ..backend.platform_helpers import Api, add_user, close_platform, make_platform, start_worker, upload_bytes, \
        wait_run

    p = make_platform(tmp_path, "embedded", queue="toy")
    try:
        add_user(p, "toy@example.org", org_admin=True)
        api = Api(p, "toy@example.org")
        steps = {s["name"]: s for s in api.get("/api/v1/steps").json()["items"]}
        assert list(steps) == ["gnss", "georef", "dense", "dtm", "volumes", "design", "datum", "exports", "toy", "report"]
        toy = steps["toy"]
        assert toy["options_schema"]["properties"]["repeat"]["anyOf"][0] == {"type": "integer", "minimum": 1,
                                                                             "maximum": 5}
        assert toy["products"][0]["needs"] == ["toy/hello.txt"]
        site = api.post("/api/v1/sites", json={"name": "Toy", "crs": "EPSG:32631"}).json()
        survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "toy"}).json()
        r = upload_bytes(api, survey["id"], "survey.json", b'{"project_crs": "EPSG:32631"}')
        assert r.status_code == 200, r.text
        # a bad option is refused at run creation, naming the step and the option, before anything runs
        r = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["toy"], "settings": {"toy": {"repeat": 9}}})
        assert r.status_code == 422 and "toy settings: repeat: 9 is above the maximum 5" in r.text
        r = api.post(f"/api/v1/surveys/{survey['id']}/runs",
                     json={"steps": ["georef"], "settings": {"georef": {"camera_model": "pinhole"}}})
        assert r.status_code == 422 and "camera_model: 'pinhole' is not one of radial, brown, fisheye" in r.text
        r = api.patch(f"/api/v1/surveys/{survey['id']}", json={"settings": {"gnss": {"elmsk": 10}}})
        assert r.status_code == 422 and "gnss settings: elmsk: unknown option" in r.text
        start_worker(p, "toy", beat=False, step_plugins=PLUGIN)
        run = api.post(f"/api/v1/surveys/{survey['id']}/runs",
                       json={"steps": ["toy"], "settings": {"toy": {"repeat": 3, "greeting": "hi"}}}).json()
        final = wait_run(api, run["id"], timeout_s=120)
        assert final["state"] == "succeeded", final
        step = next(s for s in final["step_details"] if s["name"] == "toy")
        assert step["summary"]["lines"] == 3
        body = api.get(f"/api/v1/runs/{run['id']}/results/files/toy/hello.txt").text
        assert body.splitlines()[:3] == ["hi, EPSG:32631"] * 3 and "survey.json" in body.splitlines()[3:]
    finally:
        close_platform(p)


def test_the_ui_fixture_is_the_served_schema():
    """frontend/tests/fixtures/steps_with_toy.json (what the vitest of the settings form and downloads reads) is
    GET /steps with the toy step: regenerate it with
    GEOREF_STEP_PLUGINS=tests.steps.toy_step python -c "import json; from backend.services import steps_catalog as c;
    print(json.dumps({'items': [s.as_dict() for s in c.STEPS]}, indent=1))" > frontend/tests/fixtures/steps_with_toy.json"""
    code = ("import json; from backend.services import steps_catalog as c; "
            "print(json.dumps({'items': [s.as_dict() for s in c.STEPS]}))")
    live = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True,
                          env={**os.environ, "GEOREF_STEP_PLUGINS": PLUGIN, "PYTHONPATH": REPO}).stdout
    fixture = os.path.join(REPO, "frontend", "tests", "fixtures", "steps_with_toy.json")
    with open(fixture) as fh:
        assert json.load(fh) == json.loads(live), "regenerate the fixture (see this test's docstring)"
