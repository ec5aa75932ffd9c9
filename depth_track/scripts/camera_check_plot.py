#!/usr/bin/env python3
"""Plots of a camera_check report (the YAML that `camera_check --out` writes).

    /usr/bin/python3 camera_check_plot.py REPORT.yaml OUTDIR [--edge-csv edge_spread.csv]

Writes into OUTDIR:
  sigma_vs_distance.png  depth standard deviation against distance: measured (spatial and
                         temporal), the fitted sigma(z) = a + b z + c z^2 and the built-in models
                         the report lists (the layout of the thesis's figure 4.17)
  bias_vs_distance.png   camera depth minus the measured distance, with the fitted response
  focal_vs_distance.png  CAM_K per distance (as measured and with the fitted edge offset removed)
                         and the fitted constant, when a round target was measured
  edge_spread.png        the share of face returns across the target's outline per distance
                         (with --edge-csv), when a round target was measured
camera_check runs this itself with --plots DIR.
"""
import argparse
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import yaml  # noqa: E402


def finite(v):
    return isinstance(v, (int, float)) and math.isfinite(v)


def sigma_of(model, z):
    return model["sigma_const_m"] + model["sigma_linear"] * z + model["sigma_quad_per_m"] * z * z


def finish(fig, ax, outdir, name, title, xlabel, ylabel, written, legend_size=8, ncol=1):
    """Labels, grid and legend of one figure, saved as outdir/name."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=legend_size, ncol=ncol)
    ax.set_title(title)
    fig.tight_layout()
    path = os.path.join(outdir, name)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("report")
    ap.add_argument("outdir")
    ap.add_argument("--edge-csv")
    a = ap.parse_args()
    try:
        with open(a.report) as f:
            doc = yaml.safe_load(f)
        cc = doc["camera_check"]
        segs = cc["segments"]
        fit = cc["fit"]
    except (OSError, yaml.YAMLError, KeyError, TypeError) as e:
        sys.exit(f"camera_check_plot: {a.report}: not a camera_check report ({e})")
    os.makedirs(a.outdir, exist_ok=True)
    written = []

    # Distances: the laser-measured ones where given, else the camera's own depth.
    def dist(s):
        return s["reference_distance_m"] if finite(s["reference_distance_m"]) else s["camera_depth_m"]

    z = [dist(s) for s in segs]
    zmax = max(z) * 1.1 if z else 3.0
    grid = [0.05 * zmax * i / 2.0 for i in range(41)]

    # ---- sigma against distance (figure 4.17 layout)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(z, [1e3 * s["sigma_spatial_m"] for s in segs], "o", label="measured, spatial")
    zt = [(d, s["sigma_temporal_m"]) for d, s in zip(z, segs) if finite(s["sigma_temporal_m"])]
    if zt:
        ax.plot([d for d, _ in zt], [1e3 * v for _, v in zt], "x", label="measured, temporal")
    if fit["sigma_terms"] > 0:
        ax.plot(grid, [1e3 * sigma_of(fit, g) for g in grid], "-", color="k",
                label="fit: %.2f mm + %.2f mm/m z + %.2f mm/m² z²" % (
                    1e3 * fit["sigma_const_m"], 1e3 * fit["sigma_linear"],
                    1e3 * fit["sigma_quad_per_m"]))
    for name, m in (cc.get("reference_models") or {}).items():
        ax.plot(grid, [1e3 * sigma_of(m, g) for g in grid], "--", label=f"built-in {name}")
    ax.axhline(5.0, color="grey", lw=0.8, ls=":")
    ax.text(0.02 * zmax, 5.1, "5 mm (voxel size)", color="grey", fontsize=8)
    top = max([1e3 * s["sigma_spatial_m"] for s in segs] + [6.0]) * 1.3
    ax.set_ylim(0, top)
    ax.set_xlim(0, zmax)
    finish(fig, ax, a.outdir, "sigma_vs_distance.png", "Depth noise against distance",
           "distance (m)", "depth standard deviation (mm)", written)

    # ---- bias against distance
    ref = [(s["reference_distance_m"], s["camera_depth_m"]) for s in segs
           if finite(s["reference_distance_m"])]
    if ref:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        ax.plot([r for r, _ in ref], [1e3 * (c - r) for r, c in ref], "o", label="camera - measured")
        if fit["depth_fitted"]:
            ax.plot(grid, [1e3 * ((fit["depth_scale"] - 1.0) * g + fit["depth_offset_m"])
                           for g in grid], "-", color="k",
                    label="fit: scale %+.3f %%, offset %+.2f mm" % (
                        100 * (fit["depth_scale"] - 1.0), 1e3 * fit["depth_offset_m"]))
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_xlim(0, zmax)
        finish(fig, ax, a.outdir, "bias_vs_distance.png", "Depth bias against distance",
               "measured distance (m)", "depth error (mm)", written)

    # ---- focal constant against distance
    k = [(d, s["cam_k_px"], s["cam_k_edge_corrected_px"]) for d, s in zip(z, segs)
         if finite(s["cam_k_px"])]
    if k:
        fig, ax = plt.subplots(figsize=(7, 4.5))
        ax.plot([d for d, _, _ in k], [v for _, v, _ in k], "o", label="per distance (outline)")
        kc = [(d, v) for d, _, v in k if finite(v)]
        if kc:
            ax.plot([d for d, _ in kc], [v for _, v in kc], "s", mfc="none",
                    label="edge offset %+.2f px removed" % fit["edge_offset_px"])
        if finite(fit["cam_k_px"]):
            ax.axhline(fit["cam_k_px"], color="k", label="fit: CAM_K = %.1f px" % fit["cam_k_px"])
        fx = cc["intrinsics"]["fx"]
        ax.axhline(fx, color="grey", ls="--", label="camera_info fx = %.1f px" % fx)
        ax.set_xlim(0, zmax)
        finish(fig, ax, a.outdir, "focal_vs_distance.png",
               "Focal constant from the target's diameter", "distance (m)", "CAM_K (px)", written)

    # ---- edge spread functions
    if a.edge_csv and os.path.exists(a.edge_csv):
        curves = {}
        with open(a.edge_csv) as f:
            for row in csv.DictReader(f):
                curves.setdefault(row["segment"], []).append(
                    (float(row["s_px"]), float(row["face_share"])))
        if curves:
            fig, ax = plt.subplots(figsize=(7, 4.5))
            labels = {s["label"]: dist(s) for s in segs}
            for name, pts in curves.items():
                d = labels.get(name)
                ax.plot([x for x, _ in pts], [y for _, y in pts], "-",
                        label=f"{name} ({d:.2f} m)" if d else name, lw=1)
            for lvl in (0.12, 0.5, 0.88):
                ax.axhline(lvl, color="grey", lw=0.6, ls=":")
            ax.set_ylim(-0.02, 1.02)
            sp = fit["edge_spread_px"]
            finish(fig, ax, a.outdir, "edge_spread.png",
                   "Edge spread across the target's outline" +
                   (" (12-88 %%: %.2f px)" % sp if finite(sp) else ""),
                   "distance from the outline, outward (px)",
                   "share of returns on the target's face", written, legend_size=7, ncol=2)

    for p in written:
        print(f"camera_check_plot: wrote {p}")


if __name__ == "__main__":
    main()
