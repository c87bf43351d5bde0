#!/usr/bin/env python3
"""The detectability table of a palpation sweep (docs/palpation.md).

Reads the summary.json of each case (cases/r{radius}_d{depth}_k{ratio}/summary.json, written by
`voxelastic palpate-map`), and writes:
  - a CSV, one row per case: lesion radius, depth of its top under the face, stiffness ratio,
    contrast, the estimate, its in-plane distance to the lesion's axis, and whether that is
    within --found-within-mm (found);
  - a PNG drawn by `voxelastic plot` (the project's own plots): contrast against depth, one line
    per radius and ratio, filled where the lesion was found, open where not.
Python 3 standard library only; every file is written to a temporary name and renamed.
"""
import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile

CASE = re.compile(r"r([0-9.]+)_d([0-9.]+)_k([0-9.]+)$")
COLUMNS = ["lesion_radius_mm", "lesion_depth_mm", "stiffness_ratio", "contrast", "estimate_x_mm", "estimate_y_mm",
           "error_mm", "found", "peak_n_mm", "surrounding_n_mm", "points", "map_wall_s"]


def fail(message):
    print(f"detectability: error: {message}", file=sys.stderr)
    sys.exit(1)


def read_case(path, lesion_xy, found_within):
    name = os.path.basename(os.path.dirname(os.path.abspath(path)))
    m = CASE.match(name)
    if not m:
        fail(f"{path}: its folder '{name}' is not a case name r<radius>_d<depth>_k<ratio>")
    try:
        with open(path, encoding="utf-8") as f:
            s = json.load(f)
    except (OSError, ValueError) as e:
        fail(f"{path}: {e}")
    est = s.get("lesion_estimate_mm") or [None, None, None]
    ok = est[0] is not None and est[1] is not None
    error = math.hypot(est[0] - lesion_xy[0], est[1] - lesion_xy[1]) if ok else float("nan")
    st = s.get("stiffness_n_mm", {})
    return {
        "lesion_radius_mm": float(m.group(1)),
        "lesion_depth_mm": float(m.group(2)),
        "stiffness_ratio": float(m.group(3)),
        "contrast": s.get("contrast"),
        "estimate_x_mm": est[0],
        "estimate_y_mm": est[1],
        "error_mm": error,
        "found": int(ok and error <= found_within),
        "peak_n_mm": st.get("peak"),
        "surrounding_n_mm": st.get("surrounding"),
        "points": s.get("map", {}).get("points"),
        "map_wall_s": s.get("map", {}).get("wall_s"),
    }


def fmt(v):
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def write_atomically(path, write):
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=os.path.splitext(path)[1])
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def write_csv(rows, path):
    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(",".join(COLUMNS) + "\n")
            for r in rows:
                f.write(",".join(fmt(r[c]) for c in COLUMNS) + "\n")
    write_atomically(path, write)


def write_png(rows, path, found_within, voxelastic):
    """The picture, drawn by `voxelastic plot` (the project's own plots: no display, no other program)."""
    groups = sorted({(r["lesion_radius_mm"], r["stiffness_ratio"]) for r in rows})
    colours = ["#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02", "#a6761d", "#666666"]
    series = []
    for g, (radius, ratio) in enumerate(groups):
        pts = sorted((r for r in rows if (r["lesion_radius_mm"], r["stiffness_ratio"]) == (radius, ratio)),
                     key=lambda r: r["lesion_depth_mm"])
        colour = colours[g % len(colours)]
        depth = [r["lesion_depth_mm"] for r in pts]
        contrast = [r["contrast"] if r["contrast"] is not None and math.isfinite(r["contrast"]) else None
                    for r in pts]  # None (null): a gap
        dash = 1 if ratio == max(k for _, k in groups) else 2
        series.append({"title": f"r {radius:g} mm, {ratio:g}x stiffer", "x": depth, "y": contrast,
                       "line_width": 2, "dash_type": dash, "color": colour})
        series.append({"x": depth, "y": [c if r["found"] else None for c, r in zip(contrast, pts)],
                       "points": True, "point_type": 7, "color": colour})
        series.append({"x": depth, "y": [None if r["found"] else c for c, r in zip(contrast, pts)],
                       "points": True, "point_type": 6, "color": colour})
    spec = {"width": 900, "panel_height": 560, "panels": [{
        "title": "Palpation detectability: contrast (peak / surrounding stiffness) against lesion depth",
        "subtitle": f"filled: the estimate lies within {found_within:g} mm of the lesion axis (found); open: missed",
        "xlabel": "depth of the lesion's top under the surface (mm)",
        "ylabel": "contrast",
        "key": "outside right top",
        "yrange": "[0.9:*]",
        "series": series}]}

    def write(tmp):
        res = subprocess.run([voxelastic, "-q", "plot", "-", "-o", tmp], input=json.dumps(spec), capture_output=True,
                             text=True, check=False)
        if res.returncode != 0 or not os.path.exists(tmp) or not os.path.getsize(tmp):
            fail(f"voxelastic plot failed drawing {path}: {res.stderr.strip() or res.returncode}")
    write_atomically(path, write)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("summaries", nargs="+", help="cases/<case>/summary.json files")
    p.add_argument("--lesion-xy-mm", required=True, help="the lesion's axis X,Y in the face's plane, mm")
    p.add_argument("--found-within-mm", type=float, default=2.0)
    p.add_argument("--csv", required=True)
    p.add_argument("--png")
    p.add_argument("--voxelastic", default="voxelastic", help="the voxelastic program that draws the PNG")
    a = p.parse_args()
    try:
        lesion_xy = [float(v) for v in a.lesion_xy_mm.split(",")]
        if len(lesion_xy) != 2:
            raise ValueError
    except ValueError:
        fail(f"--lesion-xy-mm '{a.lesion_xy_mm}' is not X,Y in mm")
    rows = [read_case(s, lesion_xy, a.found_within_mm) for s in a.summaries]
    rows.sort(key=lambda r: (r["lesion_radius_mm"], r["stiffness_ratio"], r["lesion_depth_mm"]))
    write_csv(rows, a.csv)
    if a.png:
        write_png(rows, a.png, a.found_within_mm, a.voxelastic)
    found = sum(r["found"] for r in rows)
    print(f"detectability: {len(rows)} cases, {found} found within {a.found_within_mm:g} mm -> {a.csv}")


if __name__ == "__main__":
    main()
