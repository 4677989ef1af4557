"""Force profiles and parameter files: formats and one-line refusals."""

from __future__ import annotations

import numpy as np
import pytest

from rig.inputs import profiles
from rig.inputs.params import Parameters


def write(tmp_path, text, name="p.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_shipped_profiles(forte, piano):
    assert forte.peak == 30.0 and piano.peak == 1.1
    assert forte.duration == pytest.approx(0.6) and piano.duration == pytest.approx(0.7)
    for p in (forte, piano):
        assert p.at(0.0) == 0.0 and p.at(p.duration) == 0.0


def test_points_and_csv_forms(tmp_path):
    p = profiles.load(write(tmp_path, "points: [[0, 0], [0.01, 2], [0.02, 0]]\n"))
    assert p.at(0.005) == pytest.approx(1.0)
    csv = write(tmp_path, "time_s,force_N\n0,0\n0.01,3\n0.03,0\n", "f.csv")
    assert profiles.load(csv).at(0.02) == pytest.approx(1.5)
    ref = profiles.load(write(tmp_path, "name: from csv\ncsv: f.csv\n"))
    np.testing.assert_array_equal(ref.force, [0, 3, 0])


@pytest.mark.parametrize("text, field", [
    ("points: [[0, 0], [0.02, 1], [0.01, 2]]", "points[2] time"),
    ("points: [[0, 0], [0.01, .nan]]", "points[1] force"),
    ("points: [[0, 0], [0.01, 500]]", "points[1] force"),
    ("points: [[0, 0], [0.01, -1]]", "points[1] force"),
    ("points: [[0, 0], [0.01, 1]]\nspeed: 3", "speed"),
    ("segments: [{hold: 0.1}, {ramp: -0.01, to: 3}]", "segments[1]"),
    ("segments: [{hold: 0.1}, {ramp: 0.01, too: 3}]", "segments[1]"),
    ("points: [[0, 0], [0.01, abc]]", "points[1] force"),
])
def test_bad_profiles_are_refused_naming_the_field(tmp_path, text, field):
    with pytest.raises(ValueError) as err:
        profiles.load(write(tmp_path, text))
    message = str(err.value)
    assert field in message and "\n" not in message


def test_force_limit_is_configurable(tmp_path):
    path = write(tmp_path, "points: [[0, 0], [0.01, 40]]")
    assert profiles.load(path).peak == 40
    with pytest.raises(ValueError, match="above the force limit of 35"):
        profiles.load(path, force_limit=35)


def test_parameter_overrides(tmp_path):
    path = write(tmp_path, "contacts: {4: {D: 3.0}}\nbodies: {key: {mass: 0.13}}\n")
    p = Parameters.from_file(path)
    assert p.get("contacts.4.D") == 3.0 and p.get("bodies.key.mass") == 0.13
    assert Parameters.default().get("contacts.4.D") == 2.446  # the defaults are untouched
    assert "contacts.12.a" in set(p.paths())


@pytest.mark.parametrize("text, expected", [
    ("bodies: {key: {mas: 0.1}}", "bodies.key.mas"),
    ("contacts: {15: {D: 1}}", "id 15"),
    ("gravity: fast", "gravity"),
    ("bodies: {key: {com: [1, 2, 3]}}", "bodies.key.com"),
])
def test_bad_parameter_files_are_refused(tmp_path, text, expected):
    with pytest.raises(ValueError) as err:
        Parameters.from_file(write(tmp_path, text))
    assert expected in str(err.value) and "\n" not in str(err.value)
