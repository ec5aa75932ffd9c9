"""Helpers shared by the Python rostests of this folder."""
from catkin.find_in_workspaces import find_in_workspaces


def tool(project, name):
    """The built executable `name` of `project` (devel or install space)."""
    found = find_in_workspaces(["libexec"], project=project, path=name, first_match_only=True)
    if not found:
        raise RuntimeError("%s/%s is not built" % (project, name))
    return found[0]


def hall1_d435_bag(out_dir, name, frames, extra=(), seed=None):
    """The ServoTruck Hall1 scenario with D435 noise (config/scenarios/Hall1.yaml with `noise:
    d435`, optionally another noise seed), its first `frames` frames written as
    `out_dir/name.bag` by make_scenario_bag (uncompressed; `extra`: more of its arguments)."""
    import os
    import re
    import subprocess

    import rospkg

    root = os.path.dirname(os.path.realpath(rospkg.RosPack().get_path("depth_track")))
    with open(os.path.join(root, "config", "scenarios", "Hall1.yaml")) as f:
        text = f.read()
    text = re.sub(r"^noise:\s*\S+", "noise: d435", text, count=1, flags=re.M)
    if seed is not None:
        text = re.sub(r"^seed:\s*\S+", "seed: %d" % seed, text, count=1, flags=re.M)
    text = re.sub(r"^name:\s*\S+", "name: " + name, text, count=1, flags=re.M)
    scenario = os.path.join(out_dir, name + ".yaml")
    with open(scenario, "w") as f:
        f.write(text)
    subprocess.run([tool("rig_drivers", "make_scenario_bag"), "--scenario", scenario,
                    "--out-dir", out_dir, "--max-frames", str(frames), "--compression", "none"]
                   + list(extra), check=True, stdout=subprocess.DEVNULL)
    return os.path.join(out_dir, name + ".bag")


def replay_and_evaluate(out_dir, bag, motion_prior, offline_priors):
    """launch/replay.launch on `bag` at half rate (every frame reaches the graph in order even on
    a loaded machine; the D435 scenario bags are in millimetres) with `motion_prior`, saving its
    trajectory to out_dir/graph_trajectory.txt; then evaluate_bag on the same bag with each of
    `offline_priors`: a prior's name, or (name, prior, [further evaluate_bag arguments]).
    Returns (roslaunch's output, {name: (completed process, its out dir)})."""
    import os
    import subprocess

    import rospkg

    root = os.path.dirname(os.path.realpath(rospkg.RosPack().get_path("depth_track")))
    launch = subprocess.run(
        ["roslaunch", os.path.join(root, "launch", "replay.launch"), "bag:=" + bag,
         "rate:=0.5", "depth_scale:=0.001", "motion_prior:=" + motion_prior,
         "trajectory_path:=" + os.path.join(out_dir, "graph_trajectory.txt"),
         "map_path:=" + os.path.join(out_dir, "graph_map.bt"),
         "table_path:=" + os.path.join(out_dir, "table.txt")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    runs = {}
    for entry in offline_priors:
        name, prior, extra = (entry, entry, []) if isinstance(entry, str) else entry
        out = os.path.join(out_dir, name)
        run = subprocess.run(
            [tool("depth_track", "evaluate_bag"), bag, "--out-dir", out, "--quiet",
             "--latency-scan", "0", "--motion-prior", prior] + list(extra),
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
        runs[name] = (run, out)
    return launch.stdout, runs


def tum_poses(path):
    """The rows of a TUM trajectory file as lists of floats (comments left out)."""
    return [[float(x) for x in l.split()] for l in open(path) if l.strip() and not l.startswith("#")]


def largest_surge_error_mm(out_dir):
    """The largest |gt_errDz| of evaluate_bag's frames.csv in out_dir (mm)."""
    import csv
    import os

    with open(os.path.join(out_dir, "frames.csv")) as f:
        return max(abs(float(r["gt_errDz"])) for r in csv.DictReader(f))


def position_differences(graph, offline):
    """Frame by frame, the largest position difference (m) of two trajectories as tum_poses
    reads them (the graph's, an offline tool's); raises AssertionError when a frame's stamps
    differ by more than 1e-6 s or the two hold different numbers of frames."""
    if len(graph) != len(offline):
        raise AssertionError("%d frames against %d" % (len(graph), len(offline)))
    diffs = []
    for k, (g, o) in enumerate(zip(graph, offline)):
        if abs(g[0] - o[0]) > 1e-6:
            raise AssertionError("frame %d: stamp %.6f against %.6f" % (k, g[0], o[0]))
        diffs.append(max(abs(a - b) for a, b in zip(g[1:4], o[1:4])))
    return diffs
