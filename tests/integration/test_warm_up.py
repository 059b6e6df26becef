"""The daemon's start-up warm-up leaves no module for the first job's layers to load."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import trimesh

from slicer.plan import ON_DEMAND_MODULES

# a fresh interpreter: this test process has long loaded everything
_SCRIPT = textwrap.dedent("""
    import json, sys
    from hostd.printing.sources import warm_up
    from slicer.settings import SliceSettings
    before = {name: name in sys.modules for name in sys.argv[1:]}
    warm_up(SliceSettings(), (200.0, 200.0, 200.0))
    after = {name: name in sys.modules for name in sys.argv[1:]}
    print(json.dumps([before, after]))
""")


def test_warm_up_loads_the_modules_layers_load_on_first_use() -> None:
    done = subprocess.run([sys.executable, "-c", _SCRIPT, *ON_DEMAND_MODULES],
                          capture_output=True, text=True, check=True, timeout=120)
    before, after = json.loads(done.stdout)
    assert not before["scipy.spatial"]  # importing the daemon's slicing does not load it
    assert all(after.values()), after


def test_a_narrow_skin_layer_needs_no_module_beyond_the_warm_up(tmp_path: Path) -> None:
    """A 1.2 mm ring, whose skins are narrow bands, on a printer with arcs lays its skin
    along the band, tidied with scipy.spatial: after the warm-up nothing new is loaded."""
    ring = trimesh.creation.annulus(r_min=8.8, r_max=10.0, height=1.0)
    ring.apply_translation((100.0, 100.0, 0.5))
    mesh = tmp_path / "ring.npz"
    np.savez(mesh, vertices=ring.vertices, faces=ring.faces)
    script = textwrap.dedent("""
        import json, sys
        import numpy as np
        from hostd.printing.sources import warm_up
        from slicer.plan import SlicePlan
        from slicer.settings import SliceSettings
        settings = SliceSettings(gcode_arcs="on")  # a printer with arcs: skins run along
        if sys.argv[2] == "warm":  # the daemon warms up with its configured settings,
            warm_up(SliceSettings(), (200.0, 200.0, 200.0))  # before it knows the printer
        ring = np.load(sys.argv[1])
        loaded = set(sys.modules)
        plan = SlicePlan.from_mesh(ring["vertices"], ring["faces"], settings,
                                   (200.0, 200.0, 200.0))
        for index in range(plan.layer_count):
            plan.layer_gcode(index)
        print(json.dumps(sorted(name for name in set(sys.modules) - loaded
                                if name.split(".")[0] in ("scipy", "slicer"))))
    """)

    def new_modules(warm: str) -> list[str]:
        done = subprocess.run([sys.executable, "-c", script, str(mesh), warm],
                              capture_output=True, text=True, check=True, timeout=120)
        return list(json.loads(done.stdout.strip().splitlines()[-1]))

    assert "scipy.spatial" in new_modules("cold")  # the ring does need it
    assert new_modules("warm") == []
