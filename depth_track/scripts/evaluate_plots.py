#!/usr/bin/env python3
"""Plots of an evaluate_bag run (the files `evaluate_bag --out-dir DIR` writes).

    /usr/bin/python3 evaluate_plots.py DIR [--label NAME] [--out OUTDIR --prefix P --dpi N]
                                           [--only tracking,map_views,...]

Writes into DIR (or OUTDIR, names prefixed with P):
  tracking.png     the thesis's tracking figure: per axis (pitch, yaw, roll angles; sway, heave,
                   surge positions) the tracked value against the references (rig sensors, ground
                   truth), and beneath each the error (tracked - reference)
  frame_time.png   time per frame by stage, and the ICP error
  matches.png      cells, matched pairs and Förstner-Moonen matches per frame
  latency.png      RMS error against the shift of the sensor stream (with latency.csv)
  map_views.png    front and plan views of the final map (with map_voxels.f32): the thesis's
                   model projections, coloured by depth / height
evaluate_bag runs this itself with --plots.
"""
import argparse
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

REFS = (("sens", "rig sensors", "tab:orange"), ("gt", "ground truth", "tab:green"))
AXES = (("Tx", "pitch θx", "deg"), ("Ty", "yaw θy", "deg"), ("Tz", "roll θz", "deg"),
        ("Dx", "sway x", "mm"), ("Dy", "heave y", "mm"), ("Dz", "surge z", "mm"))


def read_csv(path):
    with open(path) as f:
        rows = list(csv.DictReader(f))
    cols = {}
    for k in rows[0].keys() if rows else []:
        vals = []
        for r in rows:
            try:
                vals.append(float(r[k]))
            except (TypeError, ValueError):
                vals.append(math.nan)
        cols[k] = np.array(vals)
    return cols


OUTPUT = {"prefix": "", "dpi": 100}


def save(fig, outdir, name, written):
    fig.tight_layout()
    path = os.path.join(outdir, OUTPUT["prefix"] + name)
    fig.savefig(path, dpi=OUTPUT["dpi"])
    plt.close(fig)
    written.append(path)


def tracking(c, t, outdir, label, written):
    """Thesis layout: value over error, one column per axis (angles top block, positions below)."""
    fig, axs = plt.subplots(4, 3, figsize=(15, 11), sharex=True,
                            gridspec_kw={"height_ratios": [2, 1, 2, 1]})
    for i, (key, name, unit) in enumerate(AXES):
        block, col = divmod(i, 3)
        top, bottom = axs[2 * block][col], axs[2 * block + 1][col]
        top.plot(t, c["p" + key], color="tab:blue", lw=1.2, label="tracked p" + key)
        for pre, ref_name, colour in REFS:
            if pre + "_" + key not in c:
                continue
            top.plot(t, c[pre + "_" + key], color=colour, lw=1.0, ls="--", label=ref_name)
            err = c[pre + "_err" + ("T" + key[1] if key[0] == "T" else key)]
            finite = err[np.isfinite(err)]
            peak = np.max(np.abs(finite)) if finite.size else math.nan
            bottom.plot(t, err, color=colour, lw=1.0,
                        label="vs %s (max |err| %.3g %s)" % (ref_name, peak, unit))
        top.set_title("%s (%s)" % (name, unit))
        top.grid(alpha=0.3)
        top.legend(fontsize=7, loc="best")
        bottom.axhline(0.0, color="k", lw=0.5)
        bottom.set_ylabel("err%s (%s)" % (key, unit), fontsize=8)
        bottom.grid(alpha=0.3)
        bottom.legend(fontsize=7, loc="best")
    for ax in axs[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("%s: tracked vs reference per axis (relative to the first pose), error beneath"
                 % label)
    save(fig, outdir, "tracking.png", written)


def frame_time(c, t, outdir, label, written):
    fig, (a, b) = plt.subplots(2, 1, figsize=(11, 7), sharex=True,
                               gridspec_kw={"height_ratios": [2, 1]})
    parts = [("ms_decode", "bag read + conversion"), ("ms_prefilter", "prefilter"),
             ("ms_reduce", "cell reduction"), ("ms_register", "registration"),
             ("ms_map", "map (fusion + loop closure)")]
    base = np.zeros_like(t)
    for key, name in parts:
        v = np.nan_to_num(c.get(key, np.zeros_like(t)))
        if not np.any(v > 0):
            continue
        a.fill_between(t, base, base + v, step="mid", alpha=0.6,
                       label="%s (median %.2f ms)" % (name, np.median(v)))
        base = base + v
    frame = np.nan_to_num(c["ms_frame"])
    a.plot(t, frame, color="k", lw=0.6, label="tracker + map (median %.2f ms)" % np.median(frame))
    a.axhline(1000.0 / 30.0, color="tab:red", ls=":", lw=1, label="33.3 ms (30 Hz)")
    a.set_ylabel("ms per frame")
    a.grid(alpha=0.3)
    a.legend(fontsize=8, loc="upper right")
    a.set_title("%s: time per frame by stage" % label)
    b.plot(t, c["icp_error_mm"], color="tab:purple", lw=0.8)
    bad = c["tracked"] < 0.5
    if np.any(bad):
        b.plot(t[bad], c["icp_error_mm"][bad], "rx", ms=4, label="frame flagged (not tracked)")
        b.legend(fontsize=8)
    b.set_ylabel("ICP error RMS (mm)")
    b.set_xlabel("time (s)")
    b.grid(alpha=0.3)
    save(fig, outdir, "frame_time.png", written)


def matches(c, t, outdir, label, written):
    fig, ax = plt.subplots(figsize=(11, 4.5))
    ax.plot(t, c["cells"], lw=1, label="cells kept by the reduction")
    ax.plot(t, c["matches"], lw=1, label="matched pairs (final iteration)")
    fm = np.nan_to_num(c["fm_matches"])
    if np.any(fm > 0) and np.any(fm != np.nan_to_num(c["matches"])):  # Cell Search only
        ax.plot(t, c["fm_matches"], lw=1, label="Förstner-Moonen matches")
    kf = c["keyframe"] > 0.5
    if np.any(kf):
        ax.plot(t[kf], c["matches"][kf], "k|", ms=8, label="new reference frame")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("count per frame")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("%s: matches per frame" % label)
    save(fig, outdir, "matches.png", written)


def latency(path, outdir, label, written):
    c = read_csv(path)
    with open(path) as f:
        against = [r["against"] for r in csv.DictReader(f)]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    for who, colour, lw in (("tracked", "tab:blue", 4), ("ground_truth", "tab:green", 1.5)):
        sel = np.array([x == who for x in against])
        if not np.any(sel):
            continue
        k = c["shift_frames"][sel]
        name = "sensors vs tracked" if who == "tracked" else "sensors vs ground truth"
        a.plot(k, c["rms_rot_deg"][sel], "o-", color=colour, lw=lw, label=name)
        b.plot(k, c["rms_pos_mm"][sel], "o-", color=colour, lw=lw, label=name)
    for ax, what in ((a, "RMS rotation error (deg)"), (b, "RMS position error (mm)")):
        ax.set_xlabel("sensor shift (frames; + = sensors lag the camera)")
        ax.set_ylabel(what)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("%s: latency scan" % label)
    save(fig, outdir, "latency.png", written)


def map_views(path, outdir, label, written, max_points=400000):
    p = np.fromfile(path, dtype="<f4").reshape(-1, 3)
    if p.shape[0] == 0:
        return
    if p.shape[0] > max_points:  # every k-th voxel: same picture, bounded memory
        p = p[:: int(math.ceil(p.shape[0] / max_points))]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    fig, (a, b) = plt.subplots(1, 2, figsize=(15, 6.5))
    # Front: as the start camera sees it (x right, y down -> up on the page), far drawn first.
    order = np.argsort(-z)
    s = a.scatter(x[order], -y[order], c=z[order], s=0.3, cmap="viridis", marker=",", lw=0)
    a.set_aspect("equal")
    a.set_xlabel("x right (m)")
    a.set_ylabel("up (m)")
    a.set_title("front view (start camera), colour = depth")
    fig.colorbar(s, ax=a, label="depth z (m)", shrink=0.8)
    # Plan: from above (z ahead up the page, x right), high drawn last.
    order = np.argsort(y)[::-1]
    s = b.scatter(x[order], z[order], c=-y[order], s=0.3, cmap="plasma", marker=",", lw=0)
    b.set_aspect("equal")
    b.set_xlabel("x right (m)")
    b.set_ylabel("z ahead (m)")
    b.set_title("plan view (from above), colour = height")
    fig.colorbar(s, ax=b, label="height above the start camera (m)", shrink=0.8)
    fig.suptitle("%s: final map, %d occupied voxels" % (label, p.shape[0]))
    save(fig, outdir, "map_views.png", written)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("dir")
    ap.add_argument("--label", default="")
    ap.add_argument("--out", help="write the PNGs here instead of DIR")
    ap.add_argument("--prefix", default="", help="prefix of the PNG names")
    ap.add_argument("--dpi", type=int, default=100)
    ap.add_argument("--only", default="", help="comma-separated plot names (default: all)")
    a = ap.parse_args()
    OUTPUT["prefix"], OUTPUT["dpi"] = a.prefix, a.dpi
    out = a.out or a.dir
    os.makedirs(out, exist_ok=True)
    only = set(x for x in a.only.split(",") if x)
    want = (lambda name: not only or name in only)
    frames_csv = os.path.join(a.dir, "frames.csv")
    if not os.path.exists(frames_csv):
        print("evaluate_plots: %s not found" % frames_csv, file=sys.stderr)
        return 2
    label = a.label or os.path.basename(os.path.abspath(a.dir))
    c = read_csv(frames_csv)
    if not c or len(c["stamp_s"]) == 0:
        print("evaluate_plots: %s holds no frames" % frames_csv, file=sys.stderr)
        return 2
    t = c["stamp_s"] - c["stamp_s"][0]
    written = []
    if want("tracking"):
        tracking(c, t, out, label, written)
    if want("frame_time"):
        frame_time(c, t, out, label, written)
    if want("matches"):
        matches(c, t, out, label, written)
    if want("latency") and os.path.exists(os.path.join(a.dir, "latency.csv")):
        latency(os.path.join(a.dir, "latency.csv"), out, label, written)
    if want("map_views") and os.path.exists(os.path.join(a.dir, "map_voxels.f32")):
        map_views(os.path.join(a.dir, "map_voxels.f32"), out, label, written)
    for w in written:
        print("evaluate_plots: wrote %s" % w)
    return 0


if __name__ == "__main__":
    sys.exit(main())
