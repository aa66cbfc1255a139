"""The lab profile lab.toml (pipelines.lab) declared with calib_core.settings: the documented
example read as written; each refusal names the file, the line, the dotted key, what was
expected and what was found, as a manifest's and a tolerance profile's do."""

from __future__ import annotations

import textwrap

import pytest

import pipelines.lab
from pipelines.lab import load_lab_profile

BASE = '[laboratory]\nname = "IMU Lab"\naddress = "Street 1"\n'
RT2 = '[[equipment]]\nserial = "RT-2"\ncertificate = "C-1"\n[equipment.precheck]\n'


def _example() -> str:
    """The lab.toml of pipelines.lab's documentation."""
    doc = pipelines.lab.__doc__ or ""
    block = doc.split("::\n\n", 1)[1].split("\n\nEach table", 1)[0]
    return textwrap.dedent(block) + "\n"


def test_the_documented_example_is_read_as_written(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path))
    (tmp_path / "lab.toml").write_text(_example())
    doc, path = load_lab_profile()
    assert path == tmp_path / "lab.toml"
    assert doc["laboratory"]["country"] == "DE" and doc["site"]["height_m"] == 519.0
    assert [e["serial"] for e in doc["equipment"]] == ["CUBE-7", "RT-2"]
    assert doc["equipment"][1]["precheck"]["table_angle_accuracy_arcsec"] == {
        "value": 1.5,
        "limit": 3.0,
    }
    assert doc["navigation"]["profiles"] == ["land-vehicle-outage-60s"]
    # texts as written, the shortest and the longest allowed
    (tmp_path / "lab.toml").write_text(BASE.replace('"Street 1"', '"' + "x" * 200 + '"'))
    assert len(load_lab_profile()[0]["laboratory"]["address"]) == 200


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        (BASE + "[foo]\nx = 1\n", "", "foo: unknown table; expected one of authorised_by, "),
        (BASE + 'phone = "1"\n', " line 4", "laboratory.phone: unknown field of [laboratory]"),
        ('[laboratory]\nname = "X"\n', "", "laboratory.address: required field is missing"),
        ('laboratory = "x"\n', " line 1", "laboratory: expected a table, got 'x'"),
        (
            BASE + 'accreditation = ""\n',
            " line 4",
            "laboratory.accreditation: expected one line of text (1..200 characters), got ''",
        ),  # fmt: skip
        (
            BASE.replace('"Street 1"', '"a\\nb"'),
            " line 3",
            "laboratory.address: expected one line of text (1..200 characters), got 'a\\nb'",
        ),  # fmt: skip
        (
            BASE + 'country = "de"\n',
            " line 4",
            "laboratory.country: expected an ISO 3166-1 alpha-2 code such as 'DE', got 'de'",
        ),  # fmt: skip
        ("[customer]\nname = 3\n", " line 2", "customer.name: expected text, got 3"),
        ('[signing]\ncertificate = "c.pem"\n', "", "signing.key: required field is missing"),
        ("[trust]\n", "", "trust.approvers: required field is missing"),
        ('equipment = "x"\n', " line 1", "equipment: expected list, got 'x'"),
        (
            '[[equipment]]\nserial = "x"\ncolour = "r"\n',
            " line 3",
            "equipment[0].colour: unknown field of [equipment[0]]",
        ),  # fmt: skip
        (
            '[[equipment]]\nserial = "x"\n',
            "",
            "equipment[0].certificate: required field is missing",
        ),
        (
            RT2 + "power_stability_pct = { value = -1 }\n",
            " line 5",
            "equipment[0].precheck.power_stability_pct.value: expected a non-negative number, "
            "got -1",
        ),  # fmt: skip
        (
            RT2 + "power_stability_pct = { limit = 1 }\n",
            " line 5",
            "equipment[0].precheck.power_stability_pct.value: required field is missing",
        ),
        (
            RT2 + "power_stability_pct = { value = 1, limit = inf }\n",
            " line 5",
            "equipment[0].precheck.power_stability_pct.limit: expected a non-negative number, "
            "got inf",
        ),  # fmt: skip
        (
            RT2
            + "power_stability_pct = { value = 1 }\n"
            + RT2.replace("RT-2", "RT-3")
            + "power_stability_pct = { value = 2 }\n",
            " line 10",
            "equipment[1].precheck.power_stability_pct: given twice: also in equipment[0].precheck",
        ),  # fmt: skip
        (
            "[site]\nlatitude_deg = 91\nheight_m = 1\n",
            " line 2",
            "site.latitude_deg: expected a number in [-90, 90], got 91",
        ),  # fmt: skip
        (
            "[site]\nlatitude_deg = 10\nheight_m = true\n",
            " line 3",
            "site.height_m: expected a number, got True",
        ),  # fmt: skip
        ("[site]\nlatitude_deg = 10\n", "", "site.height_m: required field is missing"),
        (
            "[navigation]\nprofiles = []\n",
            " line 2",
            "navigation.profiles: expected a list of mission profile names, got []",
        ),
        (
            '[navigation]\nprofiles = ["../x"]\n',
            " line 2",
            "navigation.profiles[0]: invalid mission profile name '../x'",
        ),  # fmt: skip
        ("navigation = 3\n", " line 1", "navigation: expected a table, got 3"),
    ],
)
def test_a_refusal_names_file_line_key_expected_and_found(
    tmp_path, monkeypatch, text: str, where: str, message: str
) -> None:
    monkeypatch.setenv("CALIB_PROFILES", str(tmp_path))
    (tmp_path / "lab.toml").write_text(text)
    with pytest.raises(ValueError) as refused:
        load_lab_profile()
    assert str(refused.value).startswith(f"lab profile {tmp_path / 'lab.toml'}{where}: {message}")
