"""`hostd tailor DIR`: the paper's dogbone experiment for any part with a load case.

Writes Linear, Stress A and Stress B G-codes at equal mass, pictures like the
paper's Fig. 16 and 17, and the apparent modulus each print is predicted to
have in the load case's tension test (the printed roads rebuilt on the voxel
grid and analysed).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
import tomllib
from pathlib import Path

from hostd.app.cli import UsageError
from hostd.app.commands.slice import load_settings
from hostd.app.commands.tailor_pictures import write_pictures
from slicer.errors import ModelError
from slicer.fea.loadcase import LOAD_SUFFIX
from slicer.fea.material import describe, file_settings
from slicer.fea.predict import Prediction, TensionTest, predict_moduli, tension_test
from slicer.fea.tailor import default_cache_dir, tailored_plan
from slicer.output.gcodefile import write_gcode
from slicer.plan import SlicePlan
from slicer.settings import SettingsError, SliceSettings, parse_assignment

VARIANTS = ("A", "B")
NAMES = {"A": "Stress A", "B": "Stress B", "optimal": "Optimal"}


def find_inputs(folder: Path) -> tuple[Path, Path, Path | None]:
    """The folder's model ``NAME.stl``, its ``NAME.load.toml`` and optional ``NAME.toml``."""
    if not folder.is_dir():
        raise UsageError(f"{folder}: no such folder")
    loads = sorted(folder.glob(f"*{LOAD_SUFFIX}"))
    models = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".stl")
    if not loads:
        raise UsageError(f"{folder}: no load case (NAME{LOAD_SUFFIX}) in the folder")
    if len(loads) > 1:
        raise UsageError(f"{folder}: more than one load case: {', '.join(p.name for p in loads)}")
    stem = loads[0].name[: -len(LOAD_SUFFIX)]
    model = next((p for p in models if p.stem == stem), None)
    if model is None:
        raise UsageError(f"{loads[0]}: its model {stem}.stl is missing")
    settings = folder / f"{stem}.toml"
    return model, loads[0], settings if settings.is_file() else None


def _settings(args, extra: Path | None) -> tuple[SliceSettings, tuple]:
    """``--config``'s slicing settings, then the folder's ``NAME.toml`` (slicing keys and
    an optional ``[material]`` table), then ``--set``."""
    settings, bed = load_settings(args.config, [])
    if extra is not None:
        try:
            settings = file_settings(tomllib.loads(extra.read_text(encoding="utf-8")), settings)
        except (SettingsError, tomllib.TOMLDecodeError, OSError, UnicodeDecodeError) as exc:
            raise UsageError(f"{extra}: {exc}") from exc
    try:
        overrides = dict(parse_assignment(a) for a in args.set)
        settings = SliceSettings.from_mapping(overrides, base=settings)
    except SettingsError as exc:
        raise UsageError(str(exc)) from exc
    return settings, bed


class _Writer:
    """Measures a trial plan's mass by writing its G-code; keeps the files by plan."""

    def __init__(self, folder: Path, stem: str) -> None:
        self.folder = folder
        self.stem = stem
        self.files: dict[int, Path] = {}

    def __call__(self, plan: SlicePlan) -> float:
        path = self.folder / f".{self.stem}-trial{len(self.files)}.gcode"
        summary = write_gcode(plan, path)
        self.files[id(plan)] = path
        return summary.filament_g

    def keep(self, plan: SlicePlan, target: Path) -> None:
        """Keep ``plan``'s file as ``target`` (writing it if it was never measured)."""
        chosen = self.files.pop(id(plan), None)
        if chosen is None:
            write_gcode(plan, target)
        else:
            os.replace(chosen, target)
        for path in self.files.values():
            path.unlink(missing_ok=True)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd tailor``."""
    p.add_argument("folder", metavar="DIR", help="holds NAME.stl, NAME.load.toml (NAME.toml)")
    p.add_argument("-o", "--output", metavar="OUTDIR", help="where to write (default DIR/out)")
    p.add_argument("--optimal", action="store_true",
                   help="also infill.stress = optimal (optimised density at equal mass)")
    p.add_argument("--config", metavar="FILE", help="take [slicing] and [printer] from FILE")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[])


def run(args) -> int:
    """Slice the folder's model three ways at equal mass, draw them, predict their moduli."""
    folder = Path(args.folder)
    model, load, extra = find_inputs(folder)
    settings, bed = _settings(args, extra)
    out = Path(args.output) if args.output else folder / "out"
    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    settings = dataclasses.replace(settings, infill_match_mass_of="", infill_target_mass_g=0.0,
                                   infill_load="")
    linear_settings = dataclasses.replace(settings, infill_field="linear")
    lines: list[str] = [describe(settings)]
    try:
        linear = SlicePlan.from_file(model, linear_settings, bed)
        target = write_gcode(linear, out / "linear.gcode").filament_g
        lines.append(f"linear.gcode: {target:.3f} g at infill.density {settings.infill_density:g}")
        plans = {"Linear": linear}
        field = None
        variants = (*VARIANTS, "optimal") if args.optimal else VARIANTS
        for variant in variants:
            wanted = dataclasses.replace(settings, infill_stress=variant,
                                         infill_target_mass_g=target)
            writer = _Writer(out, f"stress-{variant.lower()}")
            plan, tailoring = tailored_plan(model, wanted, bed, default_cache_dir(), load, writer)
            writer.keep(plan, out / f"stress-{variant.lower()}.gcode")
            plans[NAMES[variant]] = plan
            field = tailoring.field if variant != "optimal" else field
            lines += [f"stress-{variant.lower()}.gcode: {line}" for line in tailoring.lines()]
        assert field is not None
        write_pictures(out, plans, field.path)
        gcodes = {"Linear": out / "linear.gcode"}
        gcodes.update({NAMES[v]: out / f"stress-{v.lower()}.gcode" for v in variants})
        predictions = predict_moduli(model, load, settings, linear.bounds, gcodes)
        test, objective = _test_of(model, load, settings, args.optimal)
    except ModelError as exc:
        raise UsageError(str(exc)) from exc
    except SettingsError as exc:
        raise UsageError(str(exc)) from exc
    lines += _table(predictions, test, objective)
    lines.append(f"done in {time.monotonic() - started:.1f} s")
    (out / "tailor.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
    for line in lines:
        print(line)
    print(f"written to {out}/: " + ", ".join(p.name for p in sorted(out.iterdir())
                                              if not p.name.startswith(".")))
    return 0


def _test_of(model: Path, load: Path, settings: SliceSettings, optimal: bool
             ) -> tuple[TensionTest, str | None]:
    """The load case's test, and what the optimum was made for (None without it)."""
    from slicer.fea.loadcase import read_load_case
    from slicer.fea.optimal import objective_text
    from slicer.input.mesh import read_stl

    vertices, faces = read_stl(model)
    case = read_load_case(load, settings.fea_youngs_modulus_mpa, settings.fea_poisson_ratio)
    test = tension_test(vertices, faces, case)
    return test, objective_text(case, test.spans[0]) if optimal else None


def _table(predictions: list[Prediction], test: TensionTest, objective: str | None
           ) -> list[str]:
    """What a test bench would read of each print, each against Linear; the headline
    (the measure the load case names) first, and the optimiser's objective."""
    base = next(p for p in predictions if p.name == "Linear")
    spans = " / ".join(f"{s:g}" for s in test.spans)
    if test.reads == "extensometer" and base.moduli:
        headline = f"apparent modulus read by a {test.spans[0]:g} mm extensometer"
    else:
        headline = "whole-part stiffness (force over the loaded faces' displacement)"
    rows = [f"headline (the load case's test): {headline}",
            "predicted from each G-code's roads (fill and direction, perfectly bonded):"]
    for p in predictions:
        mass = "solid model" if p.name == "Solid" else f"mass {p.mass_g:.2f} g"
        parts = [f"  {p.name:9s} {mass}"]
        if p.moduli:
            values = " / ".join(f"{m / 1000:.3f}" for m in p.moduli)
            parts.append(f"modulus at {spans} mm {values} GPa")
        parts.append(f"stiffness {p.stiffness:.4g} N/mm")
        if p.name not in ("Solid", "Linear"):
            gains = [f"{100.0 * (m / b - 1.0):+.0f} %" for m, b in zip(p.moduli, base.moduli,
                                                                      strict=True)]
            if gains:
                parts.append(f"vs Linear: modulus {' / '.join(gains)}")
            parts.append(f"stiffness {100.0 * (p.stiffness / base.stiffness - 1.0):+.0f} %")
        rows.append(", ".join(parts))
    rows.append("headline vs Linear: " + ", ".join(
        f"{p.name} {100.0 * (_headline(p, test) / _headline(base, test) - 1.0):+.0f} %"
        for p in predictions if p.name not in ("Solid", "Linear")))
    if objective is not None:
        rows.append(f"the optimum makes small: {objective}")
    return rows


def _headline(p: Prediction, test: TensionTest) -> float:
    return p.modulus_mpa if test.reads == "extensometer" and p.moduli else p.stiffness
