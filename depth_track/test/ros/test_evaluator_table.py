#!/usr/bin/env python3
"""The in-graph evaluator's final table equals evaluate_bag's on the same bag (issue 11).

A short rendered RT2 run (ServoTrack with a yaw sine: ground truth and the rig's sensors both
recorded) is replayed through launch/replay.launch eval:=true on the rostest's master; the
evaluator writes the table it prints to ~table_path. evaluate_bag then scores the same bag
offline. Both build the table with the core's evaluateRun / formatRunEvaluation, but from
different inputs: the graph's poses arrive as status messages and tf, the references as
subscribed topics; evaluate_bag reads everything from the bag and runs the Tracker itself. So
the table being equal line for line says the graph tracked the same poses and the evaluator saw
the same references, at the printed precision (0.001 deg, 0.01 mm). A figure sitting on a rounding
boundary may round the other way in one of them (the graph's poses pass through messages and
tf), so each number may differ by one unit of its last printed digit; every word and every
other figure must be the same. Both start the odometry at the camera mount the bag records
(base_link -> optical frame in /tf_static), so they compute in the same frame and the
trajectories they write are the same text (6 decimals of metres, 9 of the quaternion); with
evaluate_bag at the identity they differed in the last bits and the table by 0.01 mm.
"""
import os
import re
import shutil
import subprocess
import sys
import tempfile
import unittest

import rospkg
import rostest
from ros_test_tools import tool

FRAMES = 60

NUMBER = re.compile(r"^[-+]?\d+(\.\d+)?$")


def same_line(line, other):
    """Equal words, and numbers within one unit of their last printed digit."""
    a, b = line.split(), other.split()
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if x == y:
            continue
        if not (NUMBER.match(x) and NUMBER.match(y)):
            return False
        decimals = len(x.split(".")[1]) if "." in x else 0
        if (len(y.split(".")[1]) if "." in y else 0) != decimals:
            return False
        if abs(float(x) - float(y)) > 1.001 * 10.0 ** -decimals:
            return False
    return True


def table_differences(table, report):
    """The lines of `table` that differ (same_line) from its block in `report`: [] when equal."""
    lines = table.rstrip("\n").split("\n")
    rep = report.split("\n")
    starts = [k for k in range(len(rep)) if same_line(lines[0], rep[k])]
    if not starts:
        return ["first line not in the report: " + lines[0]]
    diffs = []
    for k, line in enumerate(lines):
        other = rep[starts[0] + k] if starts[0] + k < len(rep) else ""
        if not same_line(line, other):
            diffs.append("%r vs %r" % (line, other))
    return diffs


def fields_in(fields, final):
    """Whether the summary `fields` (key=v1,v2 ...) appear in a row of `final`, each number within
    one unit of its last printed digit as in same_line: the graph and evaluate_bag round the same
    trajectory errors (their last bits may differ) to two decimals."""
    split = lambda text: re.sub(r"[=,]", " ", text).split()
    a, b = split(fields), split(final)
    return any(same_line(" ".join(a), " ".join(b[k:k + len(a)])) for k in range(len(b) - len(a) + 1))


class EvaluatorTable(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.dir = tempfile.mkdtemp(prefix="dt_evaluator_table_")
        # realpath first: the workspace's src/depth_track is a symlink to the checkout's folder.
        root = os.path.dirname(os.path.realpath(rospkg.RosPack().get_path("depth_track")))
        cls.bag = os.path.join(cls.dir, "RT2.bag")
        subprocess.run([tool("rig_drivers", "make_scenario_bag"), "--scenario",
                        os.path.join(root, "config", "scenarios", "RT2.yaml"), "--out-dir",
                        cls.dir, "--max-frames", str(FRAMES), "--compression", "none"],
                       check=True, stdout=subprocess.DEVNULL)
        cls.table_path = os.path.join(cls.dir, "evaluator_table.txt")
        # Half rate: every frame reaches the graph in order even on a loaded machine.
        launch = subprocess.run(
            ["roslaunch", os.path.join(root, "launch", "replay.launch"), "bag:=" + cls.bag,
             "rate:=0.5", "trajectory_path:=" + os.path.join(cls.dir, "graph_trajectory.txt"),
             "map_path:=" + os.path.join(cls.dir, "graph_map.bt"),
             "table_path:=" + cls.table_path],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
        cls.launch_log = launch.stdout
        out = os.path.join(cls.dir, "offline")
        cls.offline = subprocess.run(
            [tool("depth_track", "evaluate_bag"), cls.bag, "--out-dir", out, "--quiet"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
        with open(os.path.join(out, "report.txt")) as f:
            cls.report = f.read()

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.dir, ignore_errors=True)

    def test_table_equals_evaluate_bag(self):
        self.assertTrue(os.path.exists(self.table_path),
                        "the evaluator wrote no table; roslaunch said:\n" + self.launch_log[-3000:])
        with open(self.table_path) as f:
            lines = f.read().rstrip("\n").split("\n")
        table, fields = "\n".join(lines[:-1]), lines[-1]
        self.assertEqual(self.offline.returncode, 0, self.offline.stdout[-2000:])
        # Both references scored, so the comparison covers the sensor kinematics too.
        self.assertIn("/rig_sim/camera_pose", table)
        self.assertIn("track_state + carriage_sensors", table)
        self.assertEqual(table_differences(table, self.report), [],
                         "evaluator's table:\n%s\n\nevaluate_bag's report:\n%s" % (table, self.report))
        final = self.report.rstrip("\n").split("\n")[-1]
        self.assertTrue(fields_in(fields, final), "%r not in %r" % (fields, final))
        self.assertTrue(final.startswith("frames=%d tracked=%d " % (FRAMES, FRAMES)), final)
        # The same poses, not only the same rounded errors.
        poses = lambda path: [l for l in open(path) if l.strip() and not l.startswith("#")]
        graph = poses(os.path.join(self.dir, "graph_trajectory.txt"))
        offline = poses(os.path.join(self.dir, "offline", "trajectory.txt"))
        self.assertEqual(len(graph), FRAMES)
        self.assertEqual(graph, offline)
        # Not a table of nothing: the tracked run is within millimetres of the truth.
        ate = float(re.search(r"ate_rmse_m=(\S+)", fields).group(1))
        self.assertLess(ate, 0.005)


if __name__ == "__main__":
    rostest.rosrun("depth_track", "evaluator_table", EvaluatorTable, sys.argv)
