"""Soil catalogue (Clay, Loam, Sand, Gravel; relative density I_d) and custom YAML soils.

Reference numbers are the paper's Table 1 normalisation ranges, typed in here from the paper
(not read from ``params``), and the published correlations cited by ``soils``.
"""
from __future__ import annotations

import math
import re
import textwrap

import numpy as np
import pytest

from soil_physics import soils
from soil_msgs_py.params import TABLE1
from soil_physics.soils import CATALOGUE, SoilType, get_soil, load_soil_yaml, soil_from_dict

# Paper Table 1 normalisation ranges (phi in deg, c in Pa, gamma in N/m^3).
PHI_NORM_DEG = (17.0, 45.0)
C_NORM_PA = (0.0, 10e3)
GAMMA_NORM = (14e3, 22e3)
NAMES = ("Clay", "Loam", "Sand", "Gravel")


def test_table1_ranges_used_by_params_match_the_paper():
    assert np.allclose(np.degrees(TABLE1["phi"].norm), PHI_NORM_DEG)
    assert TABLE1["c"].norm == C_NORM_PA
    assert TABLE1["gamma"].norm == GAMMA_NORM


def test_catalogue_has_the_four_default_soils():
    assert set(NAMES) <= set(CATALOGUE)
    for name in NAMES:
        s = CATALOGUE[name]
        assert isinstance(s, SoilType) and s.name == name
    assert set(soils.COHESIVE_SOILS) == {"Clay", "Loam"}


@pytest.mark.parametrize("name", NAMES)
def test_properties_non_decreasing_in_relative_density(name):
    i_d = np.linspace(0.0, 100.0, 201)
    p = CATALOGUE[name].at(i_d)
    for field in ("phi", "c", "gamma"):
        arr = np.asarray(getattr(p, field))
        assert arr.shape == i_d.shape
        assert np.all(np.diff(arr) >= 0), (name, field)
    # stronger interlocking when dense: friction angle and unit weight strictly higher
    assert p.phi[-1] > p.phi[0] and p.gamma[-1] > p.gamma[0]


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("i_d", [0.0, 100.0, 37.5])
def test_values_inside_table1_normalisation_ranges_in_si(name, i_d):
    p = CATALOGUE[name].at(i_d)
    assert isinstance(p.phi, float) and isinstance(p.c, float) and isinstance(p.gamma, float)
    phi_deg = p.phi * 180.0 / math.pi  # SI: radians inside
    assert PHI_NORM_DEG[0] <= phi_deg <= PHI_NORM_DEG[1]
    assert C_NORM_PA[0] <= p.c <= C_NORM_PA[1]
    assert GAMMA_NORM[0] <= p.gamma <= GAMMA_NORM[1]


@pytest.mark.parametrize("name", ["Sand", "Gravel"])
def test_cohesionless_soils(name):
    p = CATALOGUE[name].at(np.linspace(0, 100, 11))
    assert np.all(np.asarray(p.c) == 0.0)


@pytest.mark.parametrize("name", ["Clay", "Loam"])
def test_cohesive_soils_have_cohesion(name):
    assert CATALOGUE[name].at(0.0).c > 0 and CATALOGUE[name].at(100.0).c > CATALOGUE[name].at(0.0).c


def test_sand_follows_meyerhof():
    """Meyerhof (1956), cited in soils.py: phi = 28 + 0.15 D_r [deg] for sand."""
    for d_r in (0.0, 25.0, 50.0, 100.0):
        assert CATALOGUE["Sand"].at(d_r).phi == pytest.approx(math.radians(28.0 + 0.15 * d_r), abs=1e-12)


def test_linear_interpolation_and_array_input():
    s = CATALOGUE["Clay"]
    lo, hi, mid = s.at(0), s.at(100), s.at(50)
    for f in ("phi", "c", "gamma"):
        assert getattr(mid, f) == pytest.approx(0.5 * (getattr(lo, f) + getattr(hi, f)), rel=1e-12)
    arr = s.at([0, 25, 100])
    np.testing.assert_allclose(arr.c, [lo.c, 0.75 * lo.c + 0.25 * hi.c, hi.c], rtol=1e-12)
    grid = s.at(np.full((2, 3), 50.0))
    assert np.shape(grid.gamma) == (2, 3) and np.allclose(grid.gamma, mid.gamma)


@pytest.mark.parametrize("name", ["clay", "CLAY", "cLaY", "Clay", "gravel", "SAND", "loam"])
def test_get_soil_case_insensitive(name):
    s = get_soil(name)
    assert s.name.lower() == name.lower() and s is CATALOGUE[s.name]


def test_unknown_soil_names_it_and_lists_known():
    with pytest.raises(ValueError) as exc:
        get_soil("Peat")
    msg = str(exc.value)
    assert "Peat" in msg
    for name in NAMES:
        assert name in msg


@pytest.mark.parametrize("bad", [-1.0, 100.5, float("nan"), float("inf"), -1e-9, [0.0, 50.0, 101.0], [np.nan, 5.0]])
def test_relative_density_out_of_range(bad):
    with pytest.raises(ValueError, match="relative_density_pct"):
        CATALOGUE["Loam"].at(bad)


def test_relative_density_edges_accepted_and_at_the_loose_and_dense_ends():
    loam = CATALOGUE["Loam"]
    for i_d, end in ((0, loam.loose), (100, loam.dense), (0.0, loam.loose), (100.0, loam.dense),
                     (np.float32(100.0), loam.dense)):
        props = loam.at(i_d)
        assert (props.phi, props.c, props.gamma) == pytest.approx((end.phi, end.c, end.gamma)), i_d


# ----------------------------------------------------------------------------------------
# Custom YAML soils.
# ----------------------------------------------------------------------------------------
def write(tmp_path, text, name="soil.yaml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


VALID_ONE = """\
name: SiltyClay
phi_deg: [20, 30]           # loose, dense
cohesion_pa: [3000, 9000]
unit_weight_n_m3: [16000, 20000]
"""


def test_load_single_soil(tmp_path):
    out = load_soil_yaml(write(tmp_path, VALID_ONE))
    assert list(out) == ["SiltyClay"]
    s = out["SiltyClay"]
    assert s.loose.phi == pytest.approx(math.radians(20)) and s.dense.phi == pytest.approx(math.radians(30))
    assert (s.loose.c, s.dense.c) == (3000.0, 9000.0)
    assert (s.loose.gamma, s.dense.gamma) == (16000.0, 20000.0)
    assert s.at(50).phi == pytest.approx(math.radians(25))
    # usable through get_soil, case-insensitively, next to the catalogue
    assert get_soil("siltyclay", out) is s
    assert get_soil("Clay", out) is CATALOGUE["Clay"]
    with pytest.raises(ValueError, match="SiltyClay"):  # listed among the known soils
        get_soil("Peat", out)


def test_load_string_path_and_list_of_soils(tmp_path):
    p = write(tmp_path, """\
        - name: Silt
          phi_deg: [26, 34]
          cohesion_pa: [0, 2000]
          unit_weight_n_m3: [16000, 19000]
          source: my lab
        - name: "  Peat  "
          phi_deg: [5.5, 12.0]
          cohesion_pa: [500.0, 1500]
          unit_weight_n_m3: [10000, 12000]
        """)
    out = load_soil_yaml(str(p))
    assert set(out) == {"Silt", "Peat"}  # name stripped
    assert out["Silt"].source == "my lab"
    assert out["Peat"].loose.phi == pytest.approx(math.radians(5.5))
    assert out["Peat"].dense.c == 1500.0


@pytest.mark.parametrize("missing", ["phi_deg", "cohesion_pa", "unit_weight_n_m3"])
def test_missing_key_names_it(tmp_path, missing):
    lines = [line for line in VALID_ONE.splitlines() if not line.startswith(missing)]
    with pytest.raises(ValueError, match=missing):
        load_soil_yaml(write(tmp_path, "\n".join(lines)))


@pytest.mark.parametrize("name_line", ["", "name: 5", "name: ''", "name: [a, b]", "name:   "])
def test_bad_name_names_it(tmp_path, name_line):
    text = VALID_ONE.replace("name: SiltyClay", name_line)
    with pytest.raises(ValueError, match="name"):
        load_soil_yaml(write(tmp_path, text))


def with_field(field: str, value: str) -> str:
    """VALID_ONE with the line of ``field`` replaced by ``field: value``."""
    return "\n".join(f"{field}: {value}" if line.startswith(field) else line for line in VALID_ONE.splitlines())


@pytest.mark.parametrize(
    "field,value",
    [
        ("phi_deg", "[twenty, 30]"),
        ("phi_deg", "['20', 30]"),
        ("cohesion_pa", "[null, 1000]"),
        ("unit_weight_n_m3", "[{a: 1}, 20000]"),
        ("phi_deg", "[.nan, 30]"),
        ("cohesion_pa", "[0, .inf]"),
    ],
)
def test_wrong_type_names_field(tmp_path, field, value):
    text = with_field(field, value)
    with pytest.raises(ValueError, match=field):
        load_soil_yaml(write(tmp_path, text))


@pytest.mark.parametrize(
    "field,value",
    [
        ("phi_deg", "[20, 95]"),
        ("phi_deg", "[-1, 30]"),
        ("phi_deg", "[20, 90]"),  # tan(90 deg) is singular: the limit is open
        ("cohesion_pa", "[-10, 1000]"),
        ("unit_weight_n_m3", "[0, 20000]"),
        ("unit_weight_n_m3", "[16000, 1.0e9]"),
    ],
)
def test_out_of_range_names_field(tmp_path, field, value):
    text = with_field(field, value)
    with pytest.raises(ValueError, match=field):
        load_soil_yaml(write(tmp_path, text))


@pytest.mark.parametrize("value", ["30", "[30]", "[20, 25, 30]", "{loose: 20, dense: 30}", "'20, 30'"])
def test_non_pair_names_field(tmp_path, value):
    text = VALID_ONE.replace("phi_deg: [20, 30]", f"phi_deg: {value}")
    with pytest.raises(ValueError, match="phi_deg"):
        load_soil_yaml(write(tmp_path, text))


def test_invalid_yaml_names_path(tmp_path):
    p = write(tmp_path, "name: [unclosed\nphi_deg: {a: \n", name="broken.yaml")
    with pytest.raises(ValueError) as exc:
        load_soil_yaml(p)
    assert str(p) in str(exc.value)


def test_a_huge_integer_is_refused_naming_the_field_and_a_short_value(tmp_path):
    """YAML has no bound on integers: a 400-digit one overflowed math.isfinite (a traceback in
    soil_sim_batch and soil_cut_report); now a ValueError naming the field, the number cut short."""
    text = VALID_ONE.replace("[3000, 9000]", f"[3000, {10**400}]")
    with pytest.raises(ValueError, match=r"cohesion_pa=\[3000, 1000.*\.\.\. \(\d+ characters\)") as exc:
        load_soil_yaml(write(tmp_path, text))
    assert len(str(exc.value)) < 300


def test_a_binary_file_names_the_file(tmp_path):
    """A file that is not UTF-8 text: the error says which file (it said only the codec's words)."""
    p = tmp_path / "soil.bin"
    p.write_bytes(b"\xff\xfe\x00\x80name: x\n")
    with pytest.raises(ValueError, match="not UTF-8") as exc:
        load_soil_yaml(p)
    assert str(p) in str(exc.value)


def test_missing_file_names_path(tmp_path):
    p = tmp_path / "nope" / "soil.yaml"
    with pytest.raises(FileNotFoundError) as exc:
        load_soil_yaml(p)
    assert str(p) in str(exc.value)
    with pytest.raises(FileNotFoundError):  # a directory is not a soil file
        load_soil_yaml(tmp_path)


@pytest.mark.parametrize("text", ["", "just a string\n", "- 1\n- 2\n", "[]\n"])
def test_non_mapping_documents_rejected_cleanly(tmp_path, text):
    """Empty file, scalar, list of scalars: a ValueError (not TypeError/AttributeError)."""
    p = write(tmp_path, text)
    if text == "[]\n":  # an empty list is "no soils", which is acceptable
        assert load_soil_yaml(p) == {}
        return
    with pytest.raises(ValueError, match="mapping"):
        load_soil_yaml(p)


def test_a_soil_name_that_would_leave_the_bag_directory_is_refused():
    """A soil's name becomes part of its bags' file names: path separators and '..' would write
    them outside --out. Names with spaces, punctuation and non-ASCII letters are fine."""
    ok = dict(phi_deg=[20, 30], cohesion_pa=[0, 0], unit_weight_n_m3=[16e3, 18e3])
    for name in ("Silty Clay", "Lehm-Boden", "Peat_2", "Clay.B", "Bödenart", "Clay (wet)", "Sand, fine", "Till's"):
        assert soil_from_dict({**ok, "name": name}).name == name
    decomposed = "Bo\u0308denart"  # macOS spells ö as o + a combining diaeresis: one name, composed
    assert soil_from_dict({**ok, "name": decomposed}).name == "Bödenart"
    for name in ("x/../../../trav", "Clay/B", "..", ".hidden", "a..b", "a\\b", "C:lay", "tab\there", 'qu"ote'):
        with pytest.raises(ValueError, match="soil YAML name=.*no path separators"):
            soil_from_dict({**ok, "name": name})

    # a bag's directory name holds the soil's name, and a file name at most 255 bytes
    assert soil_from_dict({**ok, "name": "S" * 64}).name == "S" * 64
    for name in ("S" * 65, "ö" * 33):  # bytes in UTF-8, not characters
        with pytest.raises(ValueError, match="bytes long in UTF-8, more than 64"):
            soil_from_dict({**ok, "name": name})


def test_two_soils_of_one_name_whatever_its_case_are_refused(tmp_path):
    """A soil is looked up whatever the case of its name: 'foo' found 'Foo', the other one."""
    entry = "- name: {}\n  phi_deg: [20, 30]\n  cohesion_pa: [0, 0]\n  unit_weight_n_m3: [16e3, 18e3]\n"
    p = write(tmp_path, entry.format("Foo") + entry.format("foo"))
    with pytest.raises(ValueError, match="'Foo' and 'foo' have the same name, ignoring case"):
        load_soil_yaml(p)
    p = write(tmp_path, entry.format("Foo") + entry.format("Foo"))
    with pytest.raises(ValueError, match="'Foo' and 'Foo' have the same name"):
        load_soil_yaml(p)


def test_soil_from_dict_rejects_non_mapping():
    with pytest.raises(ValueError, match="mapping"):
        soil_from_dict(["name", "x"])


# ----------------------------------------------------------------------------------------
# Regression tests for defects found in soils.py (now fixed).
# ----------------------------------------------------------------------------------------
def test_regression_boolean_accepted_as_number(tmp_path):
    """Regression (soils._pair): ``isinstance(v, (int, float))`` is True for bool, so
    ``phi_deg: [true, 30]`` (or YAML 1.1 ``yes``/``on``) silently loads phi_loose = 1 deg
    instead of raising. Fixed: ValueError naming phi_deg."""
    text = VALID_ONE.replace("phi_deg: [20, 30]", "phi_deg: [true, 30]")
    with pytest.raises(ValueError, match="phi_deg"):
        load_soil_yaml(write(tmp_path, text))


def test_regression_custom_soil_shadowed_by_catalogue_case_variant():
    """Regression (soils.get_soil): lookup is case-insensitive but the pool is keyed by exact
    name, and the catalogue is searched first. A custom soil named ``sand`` is silently
    ignored by ``get_soil('sand', custom)`` (the catalogue's Sand is returned), whereas one
    named ``Sand`` overrides the catalogue. Fixed: the custom soil wins (as for the exact
    name) or a ValueError reports the ambiguous name - never a silent choice by spelling."""
    custom = soil_from_dict(dict(name="sand", phi_deg=[20, 30], cohesion_pa=[0, 0], unit_weight_n_m3=[15e3, 18e3]))
    assert get_soil("Sand", {"Sand": custom}) is custom  # exact-case override works today
    try:
        got = get_soil("sand", {"sand": custom})
    except ValueError:
        return
    assert got is custom


def test_regression_exponent_notation_rejected(tmp_path):
    """Regression (usability, soils.load_soil_yaml): PyYAML's YAML 1.1 resolver reads ``16e3``
    and ``10e3`` (the paper's own notation, Table 1) as *strings*, so a natural soil file
    ``unit_weight_n_m3: [16e3, 20e3]`` is rejected with "each value must be a number".
    Fixed: exponent floats accepted (e.g. convert numeric strings, or a YAML 1.2 float
    resolver)."""
    text = VALID_ONE.replace("unit_weight_n_m3: [16000, 20000]", "unit_weight_n_m3: [16e3, 20e3]")
    s = load_soil_yaml(write(tmp_path, text))["SiltyClay"]
    assert (s.loose.gamma, s.dense.gamma) == (16e3, 20e3)


# ------------------------------------------------------------------ named paths (soil patches along x)
SECTIONED = """\
soils:
  - name: SiltyClay
    phi_deg: [20, 30]
    cohesion_pa: [3000, 9000]
    unit_weight_n_m3: [16000, 20000]
paths:
  sand_then_clay: ["0.0:Sand:20", "5.0:SiltyClay:90"]
  as_mappings:
    - {x_start_m: -2, soil: gravel, relative_density_pct: 40}
"""


def test_sectioned_file_has_soils_and_named_paths(tmp_path):
    from soil_msgs_py.patches import SoilPatch

    loaded = soils.load_soil_file(write(tmp_path, SECTIONED))
    assert list(loaded.soils) == ["SiltyClay"] and load_soil_yaml(write(tmp_path, SECTIONED)) == loaded.soils
    assert loaded.paths == {"sand_then_clay": (SoilPatch(0.0, "Sand", 20.0), SoilPatch(5.0, "SiltyClay", 90.0)),
                            "as_mappings": (SoilPatch(-2.0, "gravel", 40.0),)}
    only_paths = soils.load_soil_file(write(tmp_path, 'paths: {a: ["0:Clay:10"]}'))
    assert only_paths.soils == {} and list(only_paths.paths) == ["a"]
    # a patch mapping's 5e1 (a string to YAML 1.1) is the number, as in a soil's pairs
    exponent = soils.load_soil_file(write(tmp_path, "paths: {a: [{x_start_m: 0, soil: Sand, relative_density_pct: 5e1}]}"))
    assert exponent.paths == {"a": (SoilPatch(0.0, "Sand", 50.0),)}


@pytest.mark.parametrize("text, needle", [
    (SECTIONED.replace("5.0:SiltyClay", "5.0:Peat"), r"paths\.sand_then_clay\[1\]: soil='Peat' is unknown"),
    (SECTIONED.replace('"0.0:Sand:20"', '"6.0:Sand:20"'), r"paths\.sand_then_clay\[1\]\.x_start_m=5\.0 must be greater"),
    (SECTIONED.replace("Sand:20", "Sand:200"), r"paths\.sand_then_clay\[0\]\.relative_density_pct=200\.0 outside"),
    ("paths: {a: []}", r"paths\.a=\[\] must be a non-empty list"),
    ("paths: [a]", r"paths=\['a'\] must map a path name"),
    ("soils: []\nroads: {}", r"unknown section\(s\) \['roads'\]"),
    # a misspelled section alone had read "name=None must be a non-empty string"
    ("soilz:\n- {name: Silt, phi_deg: [26, 34]}", r"the keys \['soilz'\] are neither a soil's \(it needs a 'name'\) nor"),
])
def test_bad_paths_name_the_file_path_and_value(tmp_path, text, needle):
    with pytest.raises(ValueError, match=rf"soil file '.*': {needle}"):
        soils.load_soil_file(write(tmp_path, text))


@pytest.mark.parametrize("field,old,new,said", [
    ("phi_deg", "[20, 30]", "[0.35, 0.52]", "looks like radians (20.1, 29.8 deg)"),
    ("cohesion_pa", "[3000, 9000]", "[3, 9]", "kPa perhaps"),
    ("unit_weight_n_m3", "[16000, 20000]", "[1630, 2040]", "kg/m^3 perhaps"),
])
def test_a_value_in_another_units_range_is_refused_naming_the_unit(tmp_path, field, old, new, said):
    """φ in radians, c in kPa or γ in kg/m³ lie inside the wide numeric bounds and simulated a
    soil nothing like the one meant (φ 0.45° cut with 11 kN), without a word."""
    with pytest.raises(ValueError, match=f"{field}=") as exc:
        load_soil_yaml(write(tmp_path, VALID_ONE.replace(f"{field}: {old}", f"{field}: {new}")))
    assert said in str(exc.value)
    # a small φ at one density, a cohesionless soil and a light peat stay soils
    ok = VALID_ONE.replace("phi_deg: [20, 30]", "phi_deg: [1.2, 12]").replace(
        "cohesion_pa: [3000, 9000]", "cohesion_pa: [0, 10]").replace("unit_weight_n_m3: [16000, 20000]",
                                                                      "unit_weight_n_m3: [10000, 12000]")
    assert list(load_soil_yaml(write(tmp_path, ok))) == ["SiltyClay"]


def test_an_unknown_field_and_soils_keyed_by_name_are_refused_naming_them(tmp_path):
    with pytest.raises(ValueError, match=r"unknown field\(s\) \['cohesion_kpa'\]; known: \['name', 'phi_deg'"):
        load_soil_yaml(write(tmp_path, VALID_ONE + "cohesion_kpa: [3, 9]\n"))
    keyed = "soils:\n  Silt: {phi_deg: [26, 34], cohesion_pa: [500, 4000], unit_weight_n_m3: [15500, 19000]}\n"
    with pytest.raises(ValueError, match=r"soils are a mapping of names \['Silt'\]; give a list of soils, each with its name"):
        load_soil_yaml(write(tmp_path, keyed))
    with pytest.raises(ValueError, match="is empty"):
        load_soil_yaml(write(tmp_path, ""))
    for name in ("Unknown", "none"):  # the names a machine's bags carry for "no soil label"
        with pytest.raises(ValueError, match=re.escape(f"name={name!r} says 'no soil label'")):
            load_soil_yaml(write(tmp_path, VALID_ONE.replace("name: SiltyClay", f"name: '{name}'")))


def test_a_soil_replacing_a_catalogue_soil_or_falling_with_density_is_said(tmp_path, capsys):
    """Accepted, but said: a custom 'Clay' replaced the catalogue's and its bags said only 'Clay';
    phi_deg [30, 20] (the pair given dense first) fell with density without a word."""
    from soil_physics.soils import soil_file_notes
    from soil_sim_node import batch

    f = tmp_path / "mine.yaml"
    f.write_text("- {name: Clay, phi_deg: [20, 30], cohesion_pa: [3000, 9000], unit_weight_n_m3: [16000, 20000]}\n"
                 "- {name: Silt, phi_deg: [30, 20], cohesion_pa: [0, 0], unit_weight_n_m3: [18000, 17000]}\n"
                 "- {name: sand, phi_deg: [28, 43], cohesion_pa: [0, 0], unit_weight_n_m3: [15500, 20500]}\n"
                 "- {name: Marl, phi_deg: [20, 25], cohesion_pa: [9000, 1000], unit_weight_n_m3: [17000, 19000]}\n"
                 # kPa written as Pa (an outside tester's slip): all but cohesionless, said
                 "- {name: StiffSilt, phi_deg: [19, 25], cohesion_pa: [12, 18], unit_weight_n_m3: [19000, 21500]}\n"
                 # a weakly cohesive sand: its 500 Pa as kPa would be no soil's, nothing to say
                 "- {name: SandyGravel, phi_deg: [34, 44], cohesion_pa: [0, 500], unit_weight_n_m3: [17000, 21500]}\n")
    notes = soil_file_notes(load_soil_yaml(f))
    assert len(notes) == 5, notes  # the same values as the catalogue's Sand under its name: nothing to say
    assert "soil 'StiffSilt': cohesion_pa=[12, 18] is under 100 Pa at both densities" in notes[4]
    assert "soil 'Clay' replaces the catalogue's Clay" in notes[0]
    assert "phi_deg=[30, 20] falls from loose to dense" in notes[1] and "unit_weight_n_m3=[18000, 17000]" in notes[2]
    assert "soil 'Marl': cohesion_pa=[9000, 1000] falls from loose to dense" in notes[3]  # c was not checked
    args = ["--mode", "fee", "--soil-file", str(f), "--soils", "Clay", "--relative-densities", "50", "--speeds", "0.5",
            "--depths", "0.1", "--seeds", "1", "--duration", "0.5", "--workers", "1", "--quiet", "--out", str(tmp_path / "b")]
    assert batch.main(args) == 0
    assert "warning: soil 'Clay' replaces the catalogue's Clay" in capsys.readouterr().err
