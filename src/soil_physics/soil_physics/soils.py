"""Soil catalogue: Clay, Loam, Sand, Gravel and relative density I_d -> phi, c, gamma.

Vortex (paper §2.1.1) raises phi and c with relative density I_d (stronger interlocking)
and gamma with compaction (Holz 2009). Its tables are not public, so we interpolate linearly
in I_d between a loose (I_d = 0 %) and a dense (I_d = 100 %) state whose values lie inside
published typical ranges:

* Friction angle, granular soils: Meyerhof (1956), phi = 28 + 0.15 D_r [deg] for sand
  (D_r = I_d in %); gravels 3-5 deg higher (Geotechdata.info, "Angle of friction": GW/GP
  33-45 deg). Cohesive soils: Geotechdata.info typical ranges, lean clay (CL) 17-31 deg,
  silt/loam (ML) 25-35 deg, with phi for clays kept at the low end as is usual for
  total-stress parameters.
* Cohesion: Geotechdata.info "Cohesion": clays 5-20 kPa, silts/loams 0-10 kPa, clean sands
  and gravels 0. The dense ends are kept inside paper Table 1's normalisation range
  (c <= 10 kPa) so the PINN's output range covers every catalogued soil.
* Unit weight: MATHalino "Unit weights and densities of soil" and Das, Principles of
  Geotechnical Engineering, Table 3.x: moist loose sand ~15-16, dense sand ~20, gravel
  17-22, clay and silt 16-20 kN/m^3; all inside Table 1 (14-22 kN/m^3).

delta and c_a are not soil-catalogue properties here: §3.1 fixes them for every soil
(delta = 10 deg, 15 deg in the fee world; c_a = 200 Pa), see ``params``.

A user can add a soil from YAML (``load_soil_yaml``)::

    name: SiltyClay
    phi_deg: [20, 30]           # loose, dense
    cohesion_pa: [3000, 9000]
    unit_weight_n_m3: [16000, 20000]

(or a list of such mappings), and name paths whose soil changes along x (``load_soil_file``;
``soil_msgs_py.patches``) with two sections::

    soils:                      # optional: the custom soils, as above (one mapping or a list)
      - {name: SiltyClay, phi_deg: [20, 30], cohesion_pa: [3000, 9000], unit_weight_n_m3: [16000, 20000]}
    paths:                      # name -> patches 'x_start_m:soil:relative_density_pct', ordered by x
      sand_then_clay: ["0.0:Sand:20", "5.0:SiltyClay:90"]
"""
from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from soil_msgs_py.params import DEG, TABLE1
from soil_msgs_py.patches import SoilPatch, check_patches
from soil_msgs_py.values import finite_number, short_repr, yaml_exponent
from soil_msgs_py.soil_labels import UNKNOWN_SOILS, says_unknown
from soil_msgs_py.yaml_file import read_yaml


def at_density(loose, dense, relative_density_pct):
    """A soil property at relative density I_d [%]: linear from its loose (0 %) to its dense (100 %)
    value, loose + (dense − loose) · I_d / 100 (NumPy broadcasting). The one rule of every soil,
    a catalogue soil's (``SoilType.at``) and the simulator's per patch."""
    return loose + (dense - loose) * (relative_density_pct / 100.0)


@dataclass(frozen=True)
class SoilProperties:
    """Soil parameters at one relative density (SI)."""

    phi: float  # rad
    c: float  # Pa
    gamma: float  # N/m^3


@dataclass(frozen=True)
class SoilType:
    """A soil: its properties at I_d = 0 % (loose) and I_d = 100 % (dense)."""

    name: str
    loose: SoilProperties
    dense: SoilProperties
    source: str = ""

    def at(self, relative_density_pct):
        """Properties at I_d [%] (scalar or array), linear in I_d. Raises on I_d outside [0, 100]."""
        i_d = np.asarray(relative_density_pct, dtype=float)
        if not np.all(np.isfinite(i_d)) or np.any((i_d < 0.0) | (i_d > 100.0)):
            raise ValueError(f"relative_density_pct={relative_density_pct!r} outside [0, 100] %")
        out = SoilProperties(
            at_density(self.loose.phi, self.dense.phi, i_d),
            at_density(self.loose.c, self.dense.c, i_d),
            at_density(self.loose.gamma, self.dense.gamma, i_d),
        )
        if i_d.ndim == 0:
            return SoilProperties(float(out.phi), float(out.c), float(out.gamma))
        return out


def _soil(name, phi_deg, c_pa, gamma, source) -> SoilType:
    return SoilType(
        name,
        SoilProperties(phi_deg[0] * DEG, float(c_pa[0]), float(gamma[0])),
        SoilProperties(phi_deg[1] * DEG, float(c_pa[1]), float(gamma[1])),
        source,
    )


CATALOGUE: dict[str, SoilType] = {
    s.name: s
    for s in (
        _soil("Clay", (17.0, 27.0), (2e3, 10e3), (16.0e3, 20.0e3), "Geotechdata.info CL; Das"),
        _soil("Loam", (24.0, 36.0), (1e3, 6e3), (16.0e3, 20.5e3), "Geotechdata.info ML; Das"),
        _soil("Sand", (28.0, 43.0), (0.0, 0.0), (15.5e3, 20.5e3), "Meyerhof 1956; MATHalino"),
        _soil("Gravel", (32.0, 45.0), (0.0, 0.0), (17.0e3, 22.0e3), "Geotechdata.info GW/GP; MATHalino"),
    )
}
COHESIVE_SOILS = ("Clay", "Loam")
# Parameter errors are also reported for soils no denser than this relative density [%] (the
# paper's §3.2: its PINN follows φ well at lower compaction, less so in dense soils).
ID_LIMIT_PCT = 60.0


def get_soil(name: str, custom: dict[str, SoilType] | None = None) -> SoilType:
    """Look a soil up by name (case-insensitive) in the catalogue and in ``custom``."""
    pool = {**CATALOGUE, **(custom or {})}
    # a user's soil wins over a catalogue soil of the same (case-insensitive) name
    for key, soil in [*(custom or {}).items(), *CATALOGUE.items()]:
        if key.lower() == str(name).lower():
            return soil
    raise ValueError(f"soil={name!r} is unknown; known soils: {sorted(pool)}")


_UNSAFE_NAME = re.compile(r'[/\\:*?"<>|]')  # path separators and what some file systems refuse
MAX_SOIL_NAME_BYTES = 64  # a bag's directory name holds it, and a file name at most 255 bytes


def _pair(data: dict, key: str, lo: float, hi: float, unit: str) -> tuple[float, float]:
    if key not in data:
        raise ValueError(f"soil YAML is missing {key!r} ([loose, dense] in {unit})")
    value = data[key]
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ValueError(f"{key}={short_repr(value)} must be a [loose, dense] pair in {unit}")
    out = []
    for v in value:
        v = yaml_exponent(v)  # YAML 1.1 reads 16e3 as a string
        # finite_number: a 400-digit integer in the YAML is refused here, not an OverflowError
        if not finite_number(v) or not lo <= v <= hi:
            raise ValueError(f"{key}={short_repr(value)}: each value must be a number in [{lo}, {hi}] {unit}")
        out.append(float(v))
    return out[0], out[1]


def soil_from_dict(data: dict) -> SoilType:
    """Build and validate a custom soil (see module docstring for the format)."""
    if not isinstance(data, dict):
        raise ValueError(f"soil definition must be a mapping, got {type(data).__name__}")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"soil YAML name={name!r} must be a non-empty string")
    name = unicodedata.normalize("NFC", name.strip())  # one spelling of "ö" (macOS writes it decomposed)
    if _UNSAFE_NAME.search(name) or name.startswith(".") or ".." in name or not name.isprintable():
        raise ValueError(f"soil YAML name={data.get('name')!r}: no path separators, '..', leading '.', control "
                         'characters or any of : * ? " < > | (a soil\'s name becomes part of its bags\' file names)')
    if says_unknown(name):  # its bags would read as a machine's, whose soil is not known
        raise ValueError(f"soil YAML name={name!r} says 'no soil label' ({', '.join(map(repr, UNKNOWN_SOILS[1:]))}); "
                         "give the soil a name")
    if len(name.encode("utf-8")) > MAX_SOIL_NAME_BYTES:
        raise ValueError(f"soil YAML name={name[:40]!r}{'...' if len(name) > 40 else ''} is {len(name.encode('utf-8'))} "
                         f"bytes long in UTF-8, more than {MAX_SOIL_NAME_BYTES} (a soil's name becomes part of its bags' "
                         "file names, which a file system holds to 255 bytes)")
    unknown = sorted(str(k) for k in set(data) - set(SOIL_FIELDS))
    if unknown:  # a misspelt or mis-unit key (cohesion_kpa) must not be dropped in silence
        raise ValueError(f"soil YAML {name!r}: unknown field(s) {unknown}; known: {list(SOIL_FIELDS)}")
    phi_lim = TABLE1["phi"].limits
    phi = _pair(data, "phi_deg", phi_lim[0] / DEG, phi_lim[1] / DEG - 1e-9, "deg")
    c = _pair(data, "cohesion_pa", 0.0, 1e6, "Pa")
    gamma = _pair(data, "unit_weight_n_m3", 1.0, 40e3, "N/m^3")
    _check_units(phi, c, gamma)
    return _soil(name, phi, c, gamma, str(data.get("source", "user YAML")))


def soil_to_dict(soil: SoilType) -> dict:
    """``soil`` in a soils YAML's form, which ``soil_from_dict`` reads back (a calibrated config
    records the soils of its episodes so)."""
    return {"name": soil.name,
            "phi_deg": [round(soil.loose.phi / DEG, 12), round(soil.dense.phi / DEG, 12)],
            "cohesion_pa": [soil.loose.c, soil.dense.c], "unit_weight_n_m3": [soil.loose.gamma, soil.dense.gamma],
            "source": soil.source}


SOIL_FIELDS = ("name", "phi_deg", "cohesion_pa", "unit_weight_n_m3", "source")

# Below these a value is another unit's, not a soil's: no soil a bulldozer cuts weighs less than
# ~10 kN/m^3 (peat; kg/m^3 gives 1-2.5e3), a cohesion of a few Pa is nothing (kPa gives 0.5-50),
# and a friction angle below pi/2 at both densities is a radian's (a small phi is a soil, so
# only both values in radians' range are refused).
MIN_UNIT_WEIGHT_N_M3 = 5e3
MIN_COHESION_PA = 10.0
# A cohesion under this at both densities [Pa] is accepted but said: kPa written as Pa (12-18 "Pa",
# an outside tester's slip) makes a soil all but cohesionless. Only where the kPa would be a soil's
# (under 100 kPa, a very stiff clay's): a few hundred Pa is a weakly cohesive sand's, and the note
# had told its [0, 500] Pa to be 500 kPa (an outside tester's).
KPA_SLIP_PA = 100.0


def _check_units(phi_deg: tuple[float, float], c_pa: tuple[float, float], gamma_n_m3: tuple[float, float]) -> None:
    """ValueError naming the field when its values look like another unit's (radians, kPa, kg/m^3)."""
    if all(0.0 < v <= np.pi / 2 for v in phi_deg):
        raise ValueError(f"phi_deg={list(phi_deg)} looks like radians ({', '.join(f'{v / DEG:.1f}' for v in phi_deg)} "
                         "deg); give the friction angle in degrees")
    if any(0.0 < v < MIN_COHESION_PA for v in c_pa):
        raise ValueError(f"cohesion_pa={list(c_pa)}: a cohesion of a few Pa is nothing, kPa perhaps; give Pa "
                         f"(0 for a cohesionless soil, else at least {MIN_COHESION_PA:g} Pa)")
    if any(v < MIN_UNIT_WEIGHT_N_M3 for v in gamma_n_m3):
        raise ValueError(f"unit_weight_n_m3={list(gamma_n_m3)}: below {MIN_UNIT_WEIGHT_N_M3:g} N/m^3, lighter than any "
                         "soil (peat ~10 kN/m^3); kg/m^3 perhaps: give the unit weight in N/m^3 (density × 9.81)")


@dataclass(frozen=True)
class SoilFile:
    """What a soils YAML holds: custom soils by name and named paths (patches along x)."""

    soils: dict[str, SoilType]
    paths: dict[str, tuple[SoilPatch, ...]]


SECTIONS = ("soils", "paths")


def path_patches(loaded: SoilFile | None, path: str | None, patches, *, path_opt: str = "--path",
                 file_opt: str = "--soil-file", patches_opt: str = "--patch", file_shown: str = "") -> tuple | None:
    """The patches of the named ``path`` of the soils file ``loaded`` (None: no path named), as the
    simulator node, soil_sim_batch and soil_cut_report take it beside given ``patches``; ValueError
    naming the options (``path_opt`` etc., as the caller calls them) and the value."""
    if not path:
        return None
    if patches:
        raise ValueError(f"{patches_opt}={list(patches)} and {path_opt}={path!r} both give the patches: use one")
    if loaded is None:
        raise ValueError(f"{path_opt}={path!r} needs {file_opt} (a YAML with a 'paths:' section)")
    if path not in loaded.paths:
        raise ValueError(f"{path_opt}={path!r} is not a path of {file_opt}={file_shown!r}; its paths: {sorted(loaded.paths)}")
    return loaded.paths[path]


def load_soil_file(path: str | Path) -> SoilFile:
    """Load a soils YAML: one soil (a mapping), several (a list), or the sectioned form with
    ``soils:`` and/or ``paths:`` (module docstring). Every path's soils must be catalogue soils
    or soils of the file; errors name the file, the entry and the value."""
    path = Path(path)
    if path.is_dir():
        raise FileNotFoundError(f"soil file {str(path)!r} is a directory: give the YAML file in it")
    if not path.is_file():
        raise FileNotFoundError(f"soil file {str(path)!r} does not exist")
    data = read_yaml(path, "soil file")
    if data is None:
        raise ValueError(f"soil file {str(path)!r} is empty: give a soil (a mapping), a list of them, or "
                         "the sections 'soils:' and 'paths:'")
    sectioned = isinstance(data, dict) and "name" not in data and bool(set(data) & set(SECTIONS))
    if sectioned:
        unknown = sorted(set(data) - set(SECTIONS))
        if unknown:
            raise ValueError(f"soil file {str(path)!r}: unknown section(s) {unknown}; known: {list(SECTIONS)}")
        items, raw_paths = data.get("soils") or [], data.get("paths") or {}
    else:
        items, raw_paths = data, {}
    if isinstance(items, dict) and "name" not in items and items and all(isinstance(v, dict) for v in items.values()):
        raise ValueError(f"soil file {str(path)!r}: soils are a mapping of names {short_repr(sorted(map(str, items)))}; "
                         "give a list of soils, each with its name: '- {name: Silt, phi_deg: [26, 34], ...}'")
    if isinstance(items, dict) and "name" not in items:  # ('soilz:' had read "name=None must be a non-empty string")
        raise ValueError(f"soil file {str(path)!r}: the keys {short_repr(sorted(map(str, items)))} are neither a soil's "
                         f"(it needs a 'name') nor the sections {list(SECTIONS)}")
    soils = []
    for index, item in enumerate(items if isinstance(items, list) else [items]):
        try:
            soils.append(soil_from_dict(item))
        except ValueError as exc:
            raise ValueError(f"soil file {str(path)!r}, entry {index}: {exc}") from exc
    custom = {s.name: s for s in soils}
    seen: dict[str, str] = {}
    for s in soils:  # names are looked up case-insensitively (``get_soil``): two that differ in case only are one
        if s.name.lower() in seen:
            raise ValueError(f"soil file {str(path)!r}: soils {seen[s.name.lower()]!r} and {s.name!r} have the same "
                             "name, ignoring case; a soil is looked up by its name whatever the case, so each needs "
                             "its own name")
        seen[s.name.lower()] = s.name
    if not isinstance(raw_paths, dict):
        raise ValueError(f"soil file {str(path)!r}: paths={raw_paths!r} must map a path name to its patches")
    paths = {}
    for name, entries in raw_paths.items():
        where = f"paths.{name}"
        try:
            if not isinstance(entries, list) or not entries:
                raise ValueError(f"{where}={entries!r} must be a non-empty list of patches")
            # (YAML 1.1 reads 5e1 as a string: a mapping's numbers as the soils' are)
            entries = [{k: yaml_exponent(v) for k, v in e.items()} if isinstance(e, dict) else e for e in entries]
            patches = check_patches(entries, where)
            for i, p in enumerate(patches):
                try:
                    get_soil(p.soil, custom)
                except ValueError as exc:
                    raise ValueError(f"{where}[{i}]: {exc}") from None
        except ValueError as exc:
            raise ValueError(f"soil file {str(path)!r}: {exc}") from None
        paths[str(name)] = patches
    return SoilFile(custom, paths)


def soil_file_notes(custom: dict[str, SoilType]) -> list[str]:
    """What a user may not have meant in their soils (accepted, said): a soil named like a
    catalogue soil replaces it, and its bags carry only that name, so nothing tells them from the
    catalogue soil's (only a ground truth in the bags tells them apart); a property that falls
    from loose to dense ([loose, dense] given the other way round?)."""
    notes = []
    for soil in custom.values():
        same = next((c for c in CATALOGUE.values() if c.name.lower() == soil.name.lower()), None)
        if same is not None and (same.loose, same.dense) != (soil.loose, soil.dense):
            notes.append(f"soil {soil.name!r} replaces the catalogue's {same.name} (its bags say only "
                         f"'{same.name}', like the catalogue soil's): give it a name of its own to keep them apart")
        for field, unit, scale in (("phi", "phi_deg", DEG), ("c", "cohesion_pa", 1.0), ("gamma", "unit_weight_n_m3", 1.0)):
            loose, dense = getattr(soil.loose, field), getattr(soil.dense, field)
            if dense < loose:
                notes.append(f"soil {soil.name!r}: {unit}=[{loose / scale:g}, {dense / scale:g}] falls from loose to "
                             "dense (the pair is [loose, dense]: swapped?)")
        cohesion = (soil.loose.c, soil.dense.c)
        if 0.0 < max(cohesion) < KPA_SLIP_PA:  # (refused below MIN_COHESION_PA; here accepted, said)
            notes.append(f"soil {soil.name!r}: cohesion_pa=[{cohesion[0]:g}, {cohesion[1]:g}] is under {KPA_SLIP_PA:g} Pa at "
                         f"both densities, all but cohesionless: kPa perhaps (give Pa, e.g. {cohesion[1] * 1e3:g})")
    return notes


def load_soil_yaml(path: str | Path) -> dict[str, SoilType]:
    """The custom soils of a soils YAML (``load_soil_file``) by name."""
    return load_soil_file(path).soils
