"""The package works from an installed wheel, outside the checkout: the wheel is built from a copy of the sources,
installed into a fresh virtualenv in a temporary folder (the dependencies reused from this interpreter, no network),
and `companion plan` plans the shipped demo mission there, with the checkout nowhere on the path."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(args: list, cwd: Path, env: dict, timeout: float = 300.0) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(map(str, args))} failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict, Path]:
    """(the fresh venv's bin folder, an environment without the checkout, a work folder outside the checkout)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"  # built from a copy, so the build writes nothing into the checkout
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        if (ROOT / name).exists():
            shutil.copy2(ROOT / name, src / name)
    for package in ("companion", "sim", "evaluation"):
        shutil.copytree(ROOT / package, src / package, ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", tmp / "dist",
          src], cwd=tmp, env=env)
    wheel = next((tmp / "dist").glob("companion-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    for shipped in ("companion/models/monodepth2-sim-r18w025.onnx", "companion/models/monodepth2-real-nc-r18w025.onnx",
                    "companion/missions/demo-facade.yaml", "companion/viewer/static/leaflet/LICENSE", "sim/__main__.py",
                    "sim/commands.py", "evaluation/keyframes/evaluate.py", "evaluation/depth/evaluate.py"):
        assert shipped in names, f"the wheel lacks {shipped}"
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", venv], cwd=tmp, env=env)
    site = Path(_run([venv / "bin" / "python", "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=tmp, env=env).stdout.strip())
    # This interpreter's installed dependencies, appended after the venv's own site-packages; a plain path line
    # does not run the .pth files there, so an editable install of the checkout is not picked up.
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "reuse-installed-deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    _run([sys.executable, "-m", "pip", "--python", venv / "bin" / "python", "install", "--no-deps", "--no-index",
          wheel], cwd=tmp, env=env)
    work = tmp / "work"
    work.mkdir()
    return venv / "bin", env, work


def test_installed_package_is_imported_from_the_venv_not_the_checkout(installed):
    bin_dir, env, work = installed
    script = "import companion, sim, evaluation; print(companion.__file__, sim.__file__, evaluation.__file__)"
    out = _run([bin_dir / "python", "-c", script], cwd=work, env=env).stdout.split()
    for path in out:
        assert Path(path).is_relative_to(bin_dir.parent), f"{path} is not the installed copy"


def test_wheel_plans_the_shipped_demo_mission_outside_the_checkout(installed):
    bin_dir, env, work = installed
    proc = _run([bin_dir / "companion", "plan", "demo-facade", "--out", work / "plan"], cwd=work, env=env)
    assert "mission demo-facade" in proc.stdout
    summary = json.loads((work / "plan" / "summary.json").read_text())
    assert summary["estimates"]["expected_keyframes"] > 0
    assert (work / "plan" / "demo-facade.plan").is_file()


def test_wheel_registers_the_simulator_commands(installed):
    bin_dir, env, work = installed
    proc = _run([bin_dir / "companion", "demo", "--plan-only", "--out", work / "demo"], cwd=work, env=env)
    assert (work / "demo" / "plan" / "summary.json").is_file(), proc.stdout
    helped = _run([bin_dir / "companion", "--help"], cwd=work, env=env).stdout
    for command in ("demo", "record", "eval", "sim"):
        assert command in helped


def test_the_installed_simulator_starts_outside_the_checkout(installed):
    bin_dir, env, work = installed
    script = (
        "import time\n"
        "from sim.process import SimulatorProcess, child_environment\n"
        "assert 'PYTHONPATH' not in child_environment(), 'an installed sim needs no PYTHONPATH'\n"
        "sim = SimulatorProcess(speedup=1.0, log_path='vehicle.log').start()\n"
        "time.sleep(3.0)\n"
        "alive = sim.proc.poll() is None\n"
        "sim.stop()\n"
        "assert alive, open('vehicle.log').read()\n"
    )
    _run([bin_dir / "python", "-c", script], cwd=work, env=env, timeout=120)
