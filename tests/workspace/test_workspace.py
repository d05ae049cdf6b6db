"""The colcon workspace: every package under src/ is a valid ament_python package, its
console scripts resolve, and `colcon build` installs them where `ros2 run` looks. The
layout holds: packages import only packages before them in PACKAGES and declare what they
import, and only nodes and ROS glue modules import ROS.

The build test is marked ``slow`` (deselect with ``-m "not slow"``). It builds into a
temporary directory (build/, install/, log/ all outside the repository).
"""
from __future__ import annotations

import ast
import configparser
import importlib
import json
import os
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SRC = REPO / "src"
# In the order the data flows: a package may import only packages before it. The bag format
# comes right after the physics: the batch generator writes the same bags the recorder does.
PACKAGES = ("soil_msgs_py", "soil_physics", "soil_bag_tools", "anti_stall_controller", "soil_sim_node",
            "pinn_estimator", "soil_planner", "soil_discrepancy", "soil_bringup")
COLCON = Path(sys.executable).parent / "colcon"
BUILD_TIMEOUT_S = 300

# Runs setup.py with setuptools.setup replaced, in the package directory (setup.py globs
# relative paths), and prints the keyword arguments it would have passed as JSON.
_READ_SETUP = r"""
import json, runpy, sys, setuptools
captured = {}
def fake_setup(**kw):
    captured.update(kw)
setuptools.setup = fake_setup
runpy.run_path("setup.py", run_name="__main__")
print(json.dumps({k: captured.get(k) for k in ("name", "entry_points", "data_files", "packages")}))
"""


def _read_setup(pkg: str) -> dict:
    res = subprocess.run(
        [sys.executable, "-c", _READ_SETUP], cwd=SRC / pkg, capture_output=True, text=True,
        timeout=60,
    )
    assert res.returncode == 0, f"{pkg}/setup.py failed to run:\n{res.stderr}"
    return json.loads(res.stdout.strip().splitlines()[-1])


def _console_scripts(pkg: str) -> list[tuple[str, str, str]]:
    """[(script name, module, function)] declared in ``src/<pkg>/setup.py``."""
    eps = (_read_setup(pkg).get("entry_points") or {}).get("console_scripts") or []
    out = []
    for spec in eps:
        name, _, target = (s.strip() for s in spec.partition("="))
        module, _, func = (s.strip() for s in target.partition(":"))
        out.append((name, module, func))
    return out


CONSOLE_SCRIPTS = {pkg: _console_scripts(pkg) for pkg in PACKAGES}
ALL_SCRIPTS = [(pkg, *s) for pkg, scripts in CONSOLE_SCRIPTS.items() for s in scripts]


def test_package_set_under_src():
    found = sorted(p.parent.name for p in SRC.glob("*/package.xml"))
    assert found == sorted(PACKAGES)


@pytest.mark.parametrize("pkg", PACKAGES)
def test_package_is_ament_python(pkg):
    d = SRC / pkg
    root = ET.parse(d / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == pkg
    assert root.findtext("export/build_type") == "ament_python"

    cfg = configparser.RawConfigParser()
    assert cfg.read(d / "setup.cfg")
    assert cfg.get("develop", "script_dir") == f"$base/lib/{pkg}"
    assert cfg.get("install", "install_scripts") == f"$base/lib/{pkg}"

    assert (d / "resource" / pkg).is_file()
    assert (d / pkg / "__init__.py").is_file()

    setup = _read_setup(pkg)
    assert setup["name"] == pkg
    assert pkg in setup["packages"]
    data = {dest: files for dest, files in setup["data_files"]}
    assert data["share/ament_index/resource_index/packages"] == [f"resource/{pkg}"]
    assert "package.xml" in data[f"share/{pkg}"]


@pytest.mark.parametrize(
    "pkg, script, module, func", ALL_SCRIPTS, ids=[f"{p}:{s}" for p, s, _, _ in ALL_SCRIPTS]
)
def test_console_script_target_is_importable_callable(pkg, script, module, func):
    assert module.split(".")[0] == pkg, f"{script} = {module}:{func} is outside package {pkg}"
    mod = importlib.import_module(module)
    assert callable(getattr(mod, func)), f"{module}.{func} is not callable"
    runs = getattr(getattr(mod, func), "tool_module", None)  # an offline tool's entry (interrupts.tool_entry)
    if runs:
        assert runs.split(".")[0] == pkg, f"{script} runs {runs}, outside package {pkg}"
        assert callable(getattr(importlib.import_module(runs), "main", None)), f"{runs}.main"


@pytest.mark.parametrize(
    "pkg, script, module, func", ALL_SCRIPTS, ids=[f"{p}:{s}" for p, s, _, _ in ALL_SCRIPTS]
)
def test_every_console_script_is_a_node_or_stops_from_its_first_instant(pkg, script, module, func):
    """A tool's Ctrl-C or SIGTERM while it still imports, or while the interpreter exits after it,
    printed a traceback or killed it silently (−2 / −15): every console script but a node's runs
    through ``interrupts.tool_entry``. A node (it spins rclpy) leaves its signals to rclpy."""
    target = getattr(importlib.import_module(module), func)
    runs = getattr(target, "tool_module", None)
    node = "rclpy" in _imported_top_names(SRC / pkg / Path(*module.split(".")).with_suffix(".py"))
    assert bool(runs) != node, (f"{script} = {module}:{func} " + ("is a node and a tool entry" if node else
                                "is no node: give it an entry in its package's entry_points.py (interrupts.tool_entry)"))


# --- the layout: who imports whom ---------------------------------------------------------

def _imported_top_names(path: Path) -> set[str]:
    """Top-level names of every absolute import in a module, inside functions too: a lazy
    import is still a dependency once that code path runs."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


@cache
def _module_imports(pkg: str) -> dict[Path, set[str]]:
    """{module path in the repository: top-level names it imports} for ``src/<pkg>/<pkg>/**``."""
    return {path.relative_to(REPO): _imported_top_names(path) for path in sorted((SRC / pkg / pkg).rglob("*.py"))}


@cache
def _exec_depends(pkg: str) -> frozenset[str]:
    return frozenset(e.text.strip() for e in ET.parse(SRC / pkg / "package.xml").getroot().iter("exec_depend"))


def _ros_packages() -> frozenset[str]:
    """ROS packages the workspace runs on: whatever a package.xml declares that is neither a
    project package nor a python3-* system package (rclpy, std_msgs, rcl_interfaces, ...)."""
    return frozenset(d for pkg in PACKAGES for d in _exec_depends(pkg)
                     if d not in PACKAGES and not d.startswith("python3-"))


def _is_ros_glue(module: Path) -> bool:
    """Nodes (node.py, *_node.py), the message adapter (ros_adapter.py) and, in soil_bringup,
    the launcher and the live monitor: the only modules that may import ROS, so every core
    stays importable and testable without a ROS graph."""
    stem, pkg = module.stem, module.parts[1]  # src/<pkg>/<pkg>/...
    return (stem == "node" or stem.endswith("_node") or stem == "ros_adapter"
            or (pkg == "soil_bringup" and stem in ("launch", "monitor")))


@pytest.mark.parametrize("pkg", PACKAGES)
def test_imported_project_packages_are_declared_exec_depends(pkg):
    declared = _exec_depends(pkg)
    undeclared = sorted(f"{module} imports {other}" for module, names in _module_imports(pkg).items()
                        for other in sorted(names & set(PACKAGES) - {pkg} - declared))
    assert not undeclared, f"not an <exec_depend> in src/{pkg}/package.xml:\n" + "\n".join(undeclared)


@pytest.mark.parametrize("pkg", PACKAGES)
def test_imports_follow_the_package_order(pkg):
    later = set(PACKAGES[PACKAGES.index(pkg) + 1:])
    backwards = sorted(f"{module} imports {other}" for module, names in _module_imports(pkg).items()
                       for other in sorted(names & later))
    backwards += sorted(f"src/{pkg}/package.xml declares <exec_depend>{other}" for other in _exec_depends(pkg) & later)
    assert not backwards, (f"{pkg} may import only {PACKAGES[:PACKAGES.index(pkg)]}; "
                           "it depends on packages after it:\n" + "\n".join(backwards))


@pytest.mark.parametrize("pkg", PACKAGES)
def test_only_nodes_and_ros_glue_import_ros(pkg):
    ros = _ros_packages()
    assert "rclpy" in ros
    core = sorted(f"{module} imports {', '.join(sorted(names & ros))}" for module, names in _module_imports(pkg).items()
                  if names & ros and not _is_ros_glue(module))
    assert not core, ("ROS imported outside a node (node.py, *_node.py), ros_adapter.py or soil_bringup's "
                      "launch/monitor:\n" + "\n".join(core))


@pytest.fixture(scope="module")
def colcon_build(tmp_path_factory):
    """Run `colcon build` of the workspace once, entirely under a temporary directory."""
    assert COLCON.is_file(), f"colcon not found next to {sys.executable}"
    tmp = tmp_path_factory.mktemp("colcon")
    repo_outputs = [REPO / n for n in ("build", "install", "log")]
    pre_existing = {p for p in repo_outputs if p.exists()}
    cmd = [
        str(COLCON), "--log-base", str(tmp / "log"),
        "build",
        "--base-paths", str(SRC),
        "--build-base", str(tmp / "build"),
        "--install-base", str(tmp / "install"),
    ]
    if (REPO / "colcon.meta").is_file():  # what `cd <repo> && colcon build` would pick up
        cmd += ["--metas", str(REPO / "colcon.meta")]
    env = dict(os.environ, COLCON_HOME=str(tmp / "colcon_home"))  # no user defaults/mixins
    t0 = time.monotonic()
    res = subprocess.run(cmd, cwd=tmp, env=env, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    wall = time.monotonic() - t0
    print(f"colcon build: rc={res.returncode} in {wall:.1f} s")
    created_in_repo = [str(p) for p in repo_outputs if p.exists() and p not in pre_existing]
    return res, tmp / "install", wall, created_in_repo


def _tail(res, n=4000):
    return f"--- stdout ---\n{res.stdout[-n:]}\n--- stderr ---\n{res.stderr[-n:]}"


@pytest.mark.slow
def test_colcon_build_installs_console_scripts(colcon_build):
    res, install, wall, created_in_repo = colcon_build
    assert res.returncode == 0, _tail(res)
    assert not created_in_repo, f"colcon wrote into the repository: {created_in_repo}"
    for pkg in PACKAGES:
        prefix = install / pkg
        assert (prefix / "share/ament_index/resource_index/packages" / pkg).is_file()
        assert (prefix / "share" / pkg / "package.xml").is_file()
        site = list(prefix.glob("lib/python3*/site-packages"))
        assert len(site) == 1 and (site[0] / pkg / "__init__.py").is_file(), site
        for script, _module, _func in CONSOLE_SCRIPTS[pkg]:
            exe = prefix / "lib" / pkg / script  # where `ros2 run <pkg> <script>` looks
            assert exe.is_file(), f"{exe} missing; {prefix / 'lib' / pkg} has " + str(
                sorted(p.name for p in (prefix / "lib" / pkg).glob("*")))
            assert os.access(exe, os.X_OK), f"{exe} is not executable"


@pytest.mark.slow
def test_installed_console_scripts_import_from_install_space(colcon_build):
    """The targets resolve from the *installed* copies (as `ros2 run` would import them),
    not only from the source tree: catches files missing from the installed packages."""
    res, install, _wall, _ = colcon_build
    assert res.returncode == 0, _tail(res)
    if not ALL_SCRIPTS:
        pytest.skip("no console_scripts declared")
    sites = [str(p) for pkg in PACKAGES for p in (install / pkg).glob("lib/python3*/site-packages")]
    targets = [(m, f) for _p, _s, m, f in ALL_SCRIPTS]
    probe = (
        "import importlib, json, sys\n"
        "out = {}\n"
        "for m, f in json.loads(sys.argv[1]):\n"
        "    try:\n"
        "        mod = importlib.import_module(m)\n"
        "        out[m + ':' + f] = [callable(getattr(mod, f, None)), mod.__file__]\n"
        "        runs = getattr(getattr(mod, f, None), 'tool_module', None)\n"  # interrupts.tool_entry: the module it runs
        "        if runs:\n"
        "            tool = importlib.import_module(runs)\n"
        "            out[runs + ':main'] = [callable(getattr(tool, 'main', None)), tool.__file__]\n"
        "    except Exception as e:\n"
        "        out[m + ':' + f] = [False, repr(e)]\n"
        "print(json.dumps(out))\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sites + [os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run(
        [sys.executable, "-c", probe, json.dumps(targets)], cwd=install, env=env,
        capture_output=True, text=True, timeout=120,
    )
    assert r.returncode == 0, r.stderr
    found = json.loads(r.stdout.strip().splitlines()[-1])
    bad = {k: v for k, v in found.items() if not v[0]}
    assert not bad, f"console_scripts targets not importable from the install space: {bad}"
    outside = {k: v[1] for k, v in found.items() if not str(v[1]).startswith(str(install))}
    assert not outside, f"imported from outside the install space: {outside}"


def test_the_installed_contract_package_carries_its_dds_profile(colcon_build):
    """Every node loads soil_msgs_py's Fast DDS profile from beside the module: the install space
    (what `ros2 run` imports) must hold it, or each node would print an XML error and run with
    Fast DDS's 3 s acknowledgements."""
    res, install, _wall, _ = colcon_build
    assert res.returncode == 0, _tail(res)
    (profile,) = (install / "soil_msgs_py").glob("lib/python3*/site-packages/soil_msgs_py/fastdds_profile.xml")
    assert profile.read_bytes() == (SRC / "soil_msgs_py" / "soil_msgs_py" / "fastdds_profile.xml").read_bytes()
