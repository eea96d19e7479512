#!/usr/bin/env python3
"""Check that Mitsuba 3 loads a gonio `.bsdf` (RGL tensor file) and evaluates it as gonio does.

    pip install mitsuba==3.9.1     # scalar_rgb variant, CPU only
    cargo build --release --bin gonio
    cargo run --release --bin gonio -- scan examples/sample.png --sim examples/scene.toml -o out/
    python3 tools/check_bsdf_mitsuba.py out/measured.bsdf target/release/gonio

Loads the file with Mitsuba's `measured` plugin, evaluates it at a fixed set of direction pairs
(Mitsuba returns f * cos(theta_o)), and compares f with `gonio brdf eval rgl:FILE`. Prints each
pair and the largest relative difference; exits 1 above 1e-3. CI (`.ci/run`) runs it on a small scan.
"""
import json
import math
import subprocess
import sys

import mitsuba as mi

PAIRS = [(0, 30, 0), (30, 30, 180), (30, 45, 150), (45, 45, 180), (60, 20, 90), (20, 70, 0), (75, 75, 180)]


def direction(theta_deg, phi_deg):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return mi.Vector3f(math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    path, gonio = sys.argv[1], sys.argv[2]
    mi.set_variant("scalar_rgb")
    bsdf = mi.load_dict({"type": "measured", "filename": path})
    worst = 0.0
    for ti, to, po in PAIRS:
        si = mi.SurfaceInteraction3f()
        si.wi = direction(ti, 0)
        v = bsdf.eval(mi.BSDFContext(), si, direction(to, po))
        cos_o = math.cos(math.radians(to))
        f_mitsuba = [v[c] / cos_o for c in range(3)]
        out = subprocess.run(
            [gonio, "brdf", "eval", "rgl:" + path, "--wi", f"{ti},0", "--wo", f"{to},{po}", "--json"],
            capture_output=True, text=True, check=True,
        )
        f_gonio = json.loads(out.stdout)["rgb_per_sr"]
        rel = max(abs(a - b) / max(abs(b), 1e-6) for a, b in zip(f_mitsuba, f_gonio))
        worst = max(worst, rel)
        print(f"wi {ti:>2} deg, wo ({to:>2}, {po:>3}) deg: mitsuba "
              + " ".join(f"{x:.5f}" for x in f_mitsuba) + "  gonio "
              + " ".join(f"{x:.5f}" for x in f_gonio) + f"  rel diff {rel:.1e}")
    print(f"largest relative difference: {worst:.2e} over {len(PAIRS)} pairs")
    sys.exit(0 if worst <= 1e-3 else 1)


if __name__ == "__main__":
    main()
