"""[material]: the printed material's modulus, Poisson's ratio and density, and who uses them."""

from __future__ import annotations

from pathlib import Path

import pytest

from hostd.config import ConfigError, config_from_mapping
from slicer.output.gcode import filament_grams
from slicer.settings import SliceSettings


def test_the_material_sets_the_modulus_and_the_density_every_mass_uses() -> None:
    config = config_from_mapping(
        {"material": {"youngs_modulus_mpa": 1900, "poisson_ratio": 0.36, "density_g_cm3": 1.04}},
        Path("."))
    settings = config.slicing
    assert settings.fea_youngs_modulus_mpa == 1900.0
    assert settings.fea_poisson_ratio == 0.36
    assert {"fea.youngs_modulus_mpa", "filament_density"} <= config.slicing_given
    # a metre of 1.75 mm filament: 2.405 cm^3, so 2.50 g of ABS against 2.98 g of PLA
    assert filament_grams(1000.0, settings) == pytest.approx(2.5015, abs=1e-3)
    assert filament_grams(1000.0, SliceSettings()) == pytest.approx(2.9826, abs=1e-3)


@pytest.mark.parametrize(("table", "words"), [
    ({"material": {"density": 1.0}}, "material.density: unknown material key"),
    ({"material": {"density_g_cm3": 9.0}}, "material.density_g_cm3: 9"),
    ({"material": {"density_g_cm3": 1.1}, "slicing": {"filament_density": 1.2}},
     "also given as slicing setting filament_density"),
])
def test_a_bad_material_is_refused_naming_its_key(table: dict, words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        config_from_mapping(table, Path("."))
