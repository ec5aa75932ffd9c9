#!/usr/bin/env python3
"""Speed of the tracking graph on recorded runs, measured the way a robot runs it.

For each bag: launch/tracking.launch in LIVE mode with its defaults plus loop closure (fusion and
loop closure on), a private roscore, `rosbag play --clock -r R` at R = 1, 2, 3, ... until frames
are dropped (or --max-rate). Per run it reports:
  dropped    frames the graph skipped because it was behind (the status' frames_dropped, live
             mode) plus frames of the bag that never got a status
  cpu        the nodelet manager's utime+stime (from /proc) over the wall time of the playback,
             in cores (1.0 = one core busy)
  latency    stamp-to-publish latency of the registration (the status' latency_ms, on the bag's
             clock, which rosbag publishes every 1 ms here) median / p95, and the tool's own wall
             measurement from a frame's camera_info arriving to its odom -> base_link on /tf
  rejected   frames the graph refused with a status naming why (at the start: no camera mount
             on tf yet); not drops
  on time    how late the player's camera_info reached this tool against the bag's schedule
             (p99 / max, ms, the earliest message as zero): tells a stalled player or machine
             from a slow graph
  others     CPU of rosbag play (its process group) and of this tool over the same time, in
             cores: they share the two cores with the graph
  rss        peak resident memory of the manager (VmHWM) at the end of the run
  by stage   live-mode skips per nodelet from /diagnostics ("frames dropped": dropped total):
             ingest, pca_reduce, registration (the tracking chain, counted in `dropped`) and
             fusion, loop_closure (frames the map did not get; not in `dropped`)
A measurement, not a test: the machine's load average is printed with every run, since a shared
machine shifts every number. Usage:

  rosrun depth_track graph_speed.py BAG [BAG ...] [--max-rate 6] [--rates 1,2,4] [--out FILE]
  depth_track/scripts/graph_speed.py --generate RT3,Room3      (bags/generate_bags.sh into a temp
                                                                folder, niced, then measured)
"""
import argparse
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
CAMERA_INFO = "/camera/camera_info"
CLOCK_HZ = 1000
STAGES = ("ingest", "pca_reduce", "registration", "fusion", "loop_closure")


def free_port():
    s = socket.socket()
    s.bind(("", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def load_average():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def proc_cpu_s(pid):
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    # utime and stime are fields 14 and 15 of stat; fields[0] here is field 3 (state).
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def group_cpu_s(pgid):
    """utime+stime of every process in the process group (rosbag play and what it runs)."""
    total = 0.0
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open("/proc/%s/stat" % pid) as f:
                fields = f.read().rsplit(")", 1)[1].split()
            if int(fields[2]) == pgid:  # field 5 (pgrp)
                total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            continue
    return total


def self_cpu_s():
    t = os.times()
    return t.user + t.system


def proc_hwm_mb(pid):
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def find_manager(name, timeout_s=60.0):
    """pid of the nodelet manager process started by roslaunch (its __name:=)."""
    end = time.time() + timeout_s
    while time.time() < end:
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                with open("/proc/%s/cmdline" % pid, "rb") as f:
                    args = f.read().split(b"\0")
            except OSError:
                continue
            if b"manager" in args and ("__name:=" + name).encode() in args:
                return int(pid)
        time.sleep(0.2)
    raise RuntimeError("the nodelet manager %s did not start" % name)


def percentile(v, q):
    if not v:
        return float("nan")
    v = sorted(v)
    return v[min(len(v) - 1, int(q * (len(v) - 1) + 0.5))]


class Collector:
    """Statuses and tf of the graph, and the wall arrival of each frame's camera_info."""

    def __init__(self):
        import rospy
        from rig_msgs.msg import TrackingStatus
        from sensor_msgs.msg import CameraInfo
        from diagnostic_msgs.msg import DiagnosticArray
        from tf2_msgs.msg import TFMessage

        self.lock = threading.Lock()
        self.reset()
        rospy.Subscriber("/status", TrackingStatus, self.on_status, queue_size=1000)
        rospy.Subscriber("/tf", TFMessage, self.on_tf, queue_size=1000)
        rospy.Subscriber(CAMERA_INFO, CameraInfo, self.on_info, queue_size=1000)
        rospy.Subscriber("/diagnostics", DiagnosticArray, self.on_diagnostics, queue_size=100)

    def reset(self):
        with getattr(self, "lock", threading.Lock()):
            self.statuses = {}
            self.info_wall = {}
            self.tf_wall = {}
            self.stage_dropped = {}
            self.rejected = set()
            self.last_wall = time.time()

    def on_status(self, s):
        if s.input_rejected:
            with self.lock:
                self.rejected.add(s.header.stamp.to_nsec())
            return
        with self.lock:
            self.statuses[s.header.stamp.to_nsec()] = (s.latency_ms, s.frames_dropped, s.state_name)
            self.last_wall = time.time()

    def on_tf(self, m):
        now = time.time()
        with self.lock:
            for t in m.transforms:
                if t.child_frame_id == "base_link" and t.header.frame_id == "odom":
                    self.tf_wall.setdefault(t.header.stamp.to_nsec(), now)

    def on_diagnostics(self, m):
        with self.lock:
            for s in m.status:
                if not s.name.endswith(": frames dropped"):
                    continue
                for kv in s.values:
                    if kv.key == "dropped total":
                        node = s.name[:-len(": frames dropped")].split("/")[-1]
                        self.stage_dropped[node] = int(kv.value)

    def on_info(self, m):
        now = time.time()
        with self.lock:
            self.info_wall.setdefault(m.header.stamp.to_nsec(), now)


def bag_frames(bag):
    import rosbag

    with rosbag.Bag(bag) as b:
        info = b.get_type_and_topic_info().topics
        for topic in ("/camera/image_rect", "/camera/depth/image_rect_raw"):
            if topic in info:
                return topic, info[topic].message_count, b.get_end_time() - b.get_start_time()
    raise RuntimeError("%s has no depth topic" % bag)


def run_once(bag, rate, frames, duration, collector, log, config=""):
    """One playback of `bag` at `rate` through a freshly started graph."""
    import rospy

    collector.reset()
    # A name of its own: on a shared machine another graph's depth_track_manager may be running,
    # and its /proc figures would be taken for ours.
    manager = "graph_speed_manager_%d" % os.getpid()
    launch = subprocess.Popen(
        ["roslaunch", os.path.join(ROOT, "launch", "tracking.launch"), "mode:=live",
         "loop_closure:=true", "depth_scale:=0.00025", "manager:=" + manager,
         "trajectory_path:=/dev/null", "map_path:=/dev/null"]
        + (["config:=" + os.path.abspath(config)] if config else []),
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        pid = find_manager(manager)
        # Every nodelet loaded: the last one advertises loop_closure/status.
        end = time.time() + 60
        while time.time() < end:
            topics = [t for t, _ in rospy.get_published_topics()]
            if "/loop_closure/status" in topics and "/status" in topics:
                break
            time.sleep(0.3)
        time.sleep(2.0)
        load0 = load_average()
        cpu0, wall0, tool0 = proc_cpu_s(pid), time.time(), self_cpu_s()
        # -k: the player keeps its publishers after the last frame (else the last frames can be
        # lost with the connection); it is stopped once the graph answered everything.
        player = subprocess.Popen(["rosbag", "play", "--clock", "--hz=%d" % CLOCK_HZ, "-q", "-k",
                                   "-d", "1", "-r", str(rate), bag],
                                  stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        time.sleep(1.0 + duration / rate)
        # Two seconds without a status, which also lets /diagnostics (1 s period) report the end.
        while time.time() - collector.last_wall < 2.0:
            time.sleep(0.1)
        cpu1, wall1, tool1 = proc_cpu_s(pid), collector.last_wall, self_cpu_s()
        player_cpu = group_cpu_s(player.pid)
        os.killpg(player.pid, signal.SIGINT)
        player.wait(timeout=20)
        hwm = proc_hwm_mb(pid)
        load1 = load_average()
    finally:
        os.killpg(launch.pid, signal.SIGINT)
        try:
            launch.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(launch.pid, signal.SIGKILL)
            launch.wait()
    with collector.lock:
        st = dict(collector.statuses)
        by_stage = dict(collector.stage_dropped)
        rejected = len(collector.rejected - set(st))
        arrivals = sorted((k, w) for k, w in collector.info_wall.items())
        tf_lat = [1e3 * (collector.tf_wall[k] - collector.info_wall[k])
                  for k in collector.tf_wall if k in collector.info_wall]
    skipped = max([v[1] for v in st.values()], default=0)
    missing = max(0, frames - len(st) - skipped - rejected)
    late = []
    if arrivals:
        k0, w0 = arrivals[0]
        late = [(w - w0) - (k - k0) * 1e-9 / rate for k, w in arrivals]
        late = [1e3 * (x - min(late)) for x in late]
    lat = [v[0] for v in st.values()]
    tracked = sum(1 for v in st.values() if v[2] == "TRACKING")
    return {
        "rate": rate, "frames": frames, "statuses": len(st), "tracked": tracked,
        "skipped": skipped, "missing": missing, "dropped": skipped + missing,
        "rejected": rejected, "late_p99": percentile(late, 0.99),
        "late_max": max(late, default=float("nan")),
        "cpu": (cpu1 - cpu0) / (wall1 - wall0), "wall": wall1 - wall0,
        "lat_med": statistics.median(lat) if lat else float("nan"),
        "lat_p95": percentile(lat, 0.95),
        "tf_med": statistics.median(tf_lat) if tf_lat else float("nan"),
        "tf_p95": percentile(tf_lat, 0.95), "rss_mb": hwm, "load": load0 + " -> " + load1,
        "by_stage": by_stage, "player_cpu": player_cpu / (wall1 - wall0),
        "tool_cpu": (tool1 - tool0) / (wall1 - wall0),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bags", nargs="*")
    ap.add_argument("--generate", default="", help="scenarios to generate first (comma list)")
    ap.add_argument("--max-rate", type=int, default=6)
    ap.add_argument("--rates", default="", help="fixed list of rates instead of rising ones")
    ap.add_argument("--out", default="", help="also write the table here")
    ap.add_argument("--config", default="",
                    help="parameter file instead of config/tracking.yaml (A/B of a setting)")
    a = ap.parse_args()

    bags = list(a.bags)
    tmp = None
    if a.generate:
        tmp = tempfile.mkdtemp(prefix="graph_speed_")
        names = a.generate.split(",")
        subprocess.run(["nice", "-n", "10", os.path.join(ROOT, "bags", "generate_bags.sh"), tmp]
                       + names, check=True)
        bags += [os.path.join(tmp, n + ".bag") for n in names]
    if not bags:
        ap.error("no bag given (BAG ... or --generate RT3,Room3)")

    port = free_port()
    os.environ["ROS_MASTER_URI"] = "http://localhost:%d" % port
    log_dir = tempfile.mkdtemp(prefix="graph_speed_logs_")
    os.environ["ROS_HOME"] = log_dir
    log = open(os.path.join(log_dir, "runs.log"), "w")
    core = subprocess.Popen(["roscore", "-p", str(port)], stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    rows = []
    try:
        import rosgraph
        import rospy

        end = time.time() + 30
        while not rosgraph.is_master_online() and time.time() < end:
            time.sleep(0.3)
        # The tool itself stays on wall time (it measures wall latency); the graph runs on the
        # bag's clock.
        rospy.init_node("graph_speed", anonymous=True, disable_signals=True)
        rospy.set_param("/use_sim_time", True)
        collector = Collector()
        for bag in bags:
            topic, frames, duration = bag_frames(bag)
            if topic != "/camera/image_rect":
                print("%s: depth on %s, the tool plays the scenario bags' /camera/image_rect"
                      % (bag, topic))
                continue
            rates = [int(r) for r in a.rates.split(",")] if a.rates else range(1, a.max_rate + 1)
            for rate in rates:
                r = run_once(bag, rate, frames, duration, collector, log, a.config)
                r["bag"] = os.path.basename(bag)
                rows.append(r)
                print("%-12s x%d: %d/%d statuses, %d tracked, dropped %d (skipped %d, missing %d), "
                      "cpu %.2f cores, latency %.1f/%.1f ms (tf %.1f/%.1f), rss %.0f MB, "
                      "load %s" % (r["bag"], rate, r["statuses"], frames, r["tracked"],
                                   r["dropped"], r["skipped"], r["missing"], r["cpu"],
                                   r["lat_med"], r["lat_p95"], r["tf_med"], r["tf_p95"],
                                   r["rss_mb"], r["load"]), flush=True)
                print("%-12s     skipped by stage: %s; rejected %d; cpu of rosbag play %.2f, of "
                      "this tool %.2f cores; camera_info late p99 %.1f max %.1f ms" % (
                          r["bag"], ", ".join("%s %d" % (n, r["by_stage"][n]) for n in STAGES
                                              if n in r["by_stage"]),
                          r["rejected"], r["player_cpu"], r["tool_cpu"], r["late_p99"],
                          r["late_max"]), flush=True)
                if not a.rates and r["dropped"] > 0:
                    break
    finally:
        os.killpg(core.pid, signal.SIGINT)
        core.wait(timeout=20)
    table = format_table(rows)
    print(table)
    if a.out:
        with open(a.out, "w") as f:
            f.write(table + "\n")
    print("logs: %s" % log_dir)


def format_table(rows):
    """One row per bag: drops at every rate run, the highest rate up to which none were dropped,
    and the x1 run's figures (the lowest rate run when x1 was not)."""
    lines = ["| bag | frames | dropped at x1, x2, ... | highest rate with 0 drops "
             "| graph CPU (cores) | rosbag play CPU (cores) | stamp-to-tf median / p95 (ms, wall) "
             "| status latency median / p95 (ms, bag clock) | peak RSS (MB) "
             "| map frames skipped (fusion) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for bag in dict.fromkeys(r["bag"] for r in rows):
        rs = sorted((r for r in rows if r["bag"] == bag), key=lambda r: r["rate"])
        best = None
        for r in rs:
            if r["dropped"] > 0:
                break
            best = r["rate"]
        one = rs[0]
        lines.append("| %s | %d | %s | %s | %.2f | %.2f | %.1f / %.1f | %.1f / %.1f | %.0f | %s |" % (
            bag, one["frames"], ", ".join("x%d: %d" % (r["rate"], r["dropped"]) for r in rs),
            ("x%d" % best) if best else "none (drops at x%d)" % rs[0]["rate"], one["cpu"],
            one["player_cpu"], one["tf_med"], one["tf_p95"], one["lat_med"], one["lat_p95"],
            max(r["rss_mb"] for r in rs), one["by_stage"].get("fusion", "?")))
    return "\n".join(lines)

if __name__ == "__main__":
    sys.exit(main())
