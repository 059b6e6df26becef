"""Peer slicers (PrusaSlicer, CuraEngine): install them when missing and run them measured.

The command lines and settings are those of the project's peer notes: 0.2 mm layers,
0.4 mm lines, 2 perimeters, 3 top and 3 bottom layers, 20 % rectilinear/lines infill,
no support, skirt or brim, 1.75 mm filament, 200 mm bed, object centred at (100, 100).

Usage (from the repository root), to install the peers and slice one model with each:
    .venv/bin/python bench/peers.py MODEL.stl [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.measure import RunResult, run_measured

CACHE = Path(__file__).resolve().parent / ".cache"
CURA_DEB_DIR = CACHE / "cura"
BED_CENTRE = (100.0, 100.0)


@dataclass(frozen=True)
class Peer:
    """A peer slicer ready to run: its name, executable and environment."""

    name: str
    executable: str
    env: dict[str, str] = field(default_factory=dict)
    resources: Path | None = None

    def command(self, model: Path, out: Path) -> list[str]:
        """The exact command line that slices ``model`` into ``out``."""
        if self.name == "prusaslicer":
            return prusaslicer_command(self.executable, model, out)
        if self.name == "curaengine" and self.resources is not None:
            return curaengine_command(self.executable, self.resources, model, out)
        raise ValueError(f"unknown peer {self.name!r}")

    def slice(self, model: Path, out: Path, timeout: float) -> RunResult:
        """Slice ``model`` into ``out``, measured (wall time, peak RSS)."""
        return run_measured(self.command(model, out), timeout=timeout, env=self.env)


_PRUSA_WIDTHS = (
    "--extrusion-width", "--first-layer-extrusion-width", "--perimeter-extrusion-width",
    "--external-perimeter-extrusion-width", "--infill-extrusion-width",
    "--solid-infill-extrusion-width", "--top-infill-extrusion-width",
    "--support-material-extrusion-width",
)


def prusaslicer_command(exe: str, model: Path, out: Path) -> list[str]:
    """PrusaSlicer 2.5 command line with the benchmark settings."""
    args = [exe, "--export-gcode", "--layer-height", "0.2", "--first-layer-height", "0.2",
            "--nozzle-diameter", "0.4"]
    for opt in _PRUSA_WIDTHS:
        args += [opt, "0.4"]
    args += ["--perimeters", "2", "--top-solid-layers", "3", "--bottom-solid-layers", "3",
             "--fill-density", "20%", "--fill-pattern", "rectilinear", "--skirts", "0",
             "--brim-width", "0", "--filament-diameter", "1.75",
             "--center", f"{BED_CENTRE[0]:g},{BED_CENTRE[1]:g}",
             "--output", str(out), str(model)]
    return args


# CuraEngine ignores the formulas of its definitions, so every setting is passed
_CURA_SETTINGS = (
    "machine_width=200", "machine_depth=200", "machine_height=200",
    "layer_height=0.2", "layer_height_0=0.2", "machine_nozzle_size=0.4",
    "line_width=0.4", "wall_line_width_0=0.4", "wall_line_width_x=0.4", "skin_line_width=0.4",
    "infill_line_width=0.4", "skirt_brim_line_width=0.4", "support_line_width=0.4",
    "initial_layer_line_width_factor=100", "wall_line_count=2", "top_layers=3",
    "bottom_layers=3", "initial_bottom_layers=3", "infill_sparse_density=20",
    "infill_line_distance=2", "infill_pattern=lines", "infill_sparse_thickness=0.2",
    "adhesion_type=none", "support_enable=false", "material_diameter=1.75",
    "center_object=true",
)
_CURA_EXTRUDER_SETTINGS = ("material_diameter=1.75", "machine_nozzle_size=0.4")


def curaengine_command(exe: str, resources: Path, model: Path, out: Path) -> list[str]:
    """CuraEngine 4.13 command line with the benchmark settings."""
    args = [exe, "slice", "-j", str(resources / "definitions" / "fdmprinter.def.json")]
    for setting in _CURA_SETTINGS:
        args += ["-s", setting]
    args.append("-e0")
    for setting in _CURA_EXTRUDER_SETTINGS:
        args += ["-s", setting]
    args += ["-l", str(model), "-o", str(out)]
    return args


def _say(message: str) -> None:
    print(f"peers: {message}", file=sys.stderr)


def _apt_install(package: str) -> bool:
    """Install a Debian package as root; False (with a message) when that is impossible."""
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        _say(f"{package} is missing and cannot be installed here (needs root and apt-get); "
             f"install it with: apt-get install -y {package}")
        return False
    _say(f"installing {package} with apt-get (once)")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    done = subprocess.run(["apt-get", "install", "-y", "-qq", package], env=env,
                          capture_output=True, text=True, check=False, timeout=1800)
    if done.returncode != 0:
        subprocess.run(["apt-get", "update", "-qq"], env=env, capture_output=True,
                       check=False, timeout=600)
        done = subprocess.run(["apt-get", "install", "-y", "-qq", package], env=env,
                              capture_output=True, text=True, check=False, timeout=1800)
    if done.returncode != 0:
        _say(f"apt-get install {package} failed: {done.stderr.strip()[-200:]}")
        return False
    return True


def _find_or_install(binary: str, package: str) -> str | None:
    exe = shutil.which(binary)
    if exe is None and _apt_install(package):
        exe = shutil.which(binary)
    return exe


def prusaslicer() -> Peer | None:
    """PrusaSlicer, installed from the Debian package when missing; None if unavailable."""
    exe = _find_or_install("prusa-slicer", "prusa-slicer")
    if exe is None:
        _say("skipping PrusaSlicer")
        return None
    return Peer("prusaslicer", exe)


def cura_resources() -> Path | None:
    """CuraEngine's definitions folder: the `cura` package's files, extracted into the cache.

    The definitions ship only in the GUI package; its .deb is fetched with
    ``apt-get download`` and unpacked with ``dpkg -x`` without installing it.
    """
    for root in (CURA_DEB_DIR / "usr/share/cura/resources", Path("/usr/share/cura/resources")):
        if (root / "definitions" / "fdmprinter.def.json").exists():
            return root
    if not (shutil.which("apt-get") and shutil.which("dpkg")):
        _say("apt-get/dpkg missing: cannot fetch CuraEngine's definitions")
        return None
    CACHE.mkdir(parents=True, exist_ok=True)
    debs = sorted(CACHE.glob("cura_*.deb"))
    if not debs:
        _say("fetching the cura package for its definitions (apt-get download cura)")
        subprocess.run(["apt-get", "download", "-qq", "cura"], cwd=CACHE, capture_output=True,
                       check=False, timeout=900)
        debs = sorted(CACHE.glob("cura_*.deb"))
    if not debs:
        _say("apt-get download cura failed (try apt-get update first)")
        return None
    subprocess.run(["dpkg", "-x", str(debs[-1]), str(CURA_DEB_DIR)], capture_output=True,
                   check=False, timeout=600)
    root = CURA_DEB_DIR / "usr/share/cura/resources"
    return root if (root / "definitions" / "fdmprinter.def.json").exists() else None


def curaengine() -> Peer | None:
    """CuraEngine with its definitions; installed when missing; None if unavailable."""
    exe = _find_or_install("CuraEngine", "cura-engine")
    resources = cura_resources() if exe else None
    if exe is None or resources is None:
        _say("skipping CuraEngine")
        return None
    search = f"{resources / 'definitions'}:{resources / 'extruders'}"
    return Peer("curaengine", exe, env={"CURA_ENGINE_SEARCH_PATH": search}, resources=resources)


def available_peers(names: tuple[str, ...] = ("prusaslicer", "curaengine")) -> list[Peer]:
    """The requested peers that could be found or installed, in the given order."""
    makers = {"prusaslicer": prusaslicer, "curaengine": curaengine}
    peers = [makers[name]() for name in names]
    return [p for p in peers if p is not None]


def main(argv: list[str] | None = None) -> int:
    """Install the peers when missing and slice one model with each, measured."""
    parser = argparse.ArgumentParser(description="Slice one model with each peer slicer.")
    parser.add_argument("model", type=Path)
    parser.add_argument("--out", type=Path, default=Path("bench/out/gcode"))
    parser.add_argument("--timeout", type=float, default=600.0)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for peer in available_peers():
        out = args.out / f"{args.model.stem}.{peer.name}.gcode"
        result = peer.slice(args.model, out, args.timeout)
        rss = "-" if result.rss_mb is None else f"{result.rss_mb:.0f} MB"
        status = str(out) if result.ok else result.reason()
        print(f"{peer.name:12s} {result.wall_s:7.2f} s {rss:>8s}  {status}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
