#!/usr/bin/env python3
"""depth_camera's folder backend (~backend tum) on a real roscore, playing a folder in the
7-Scenes layout: frame-*.depth.png in millimetres with 65535 for no return, a 4x4 pose file per
frame and camera-intrinsics.txt, as Microsoft's 7-Scenes sequences are laid out.

The node is started by the test (rosrun) on a folder the test writes, so the folder exists before
the node reads it. It publishes one frame per ~trigger call. Checked: the intrinsics come from the
folder's camera-intrinsics.txt, not from ~fx..~cy; the image size from the frames; millimetres are
published as they are (~depth_scale_m 1 mm), 65535 and readings outside ~min/max_depth_m as 0;
the stamps are the files' (frame i at i / 30 s) 1 s later, since a stamp of 0 means "latest" to
tf. A folder with a malformed pose file stops the node with the file and line named.

A TUM-layout folder without an intrinsics file (~tum_camera): its name pointing at a Freiburg
camera, the node refuses to play it with ~fx..~cy and names the camera; ~tum_camera fr1 plays it
with the published fr1 calibration (size from the frames), ~tum_camera params with ~fx..~cy; an
unknown ~tum_camera is refused by name."""
import os
import shutil
import struct
import subprocess
import tempfile
import threading
import time
import unittest
import zlib

import rospy
import rostest
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

W, H = 8, 6
K = (61.5, 62.5, 3.5, 2.5)  # fx fy cx cy of the folder's camera-intrinsics.txt


def write_png16(path, rows):
    """A 16-bit greyscale PNG (big-endian samples, filter 0 on every row)."""
    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data +
                struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    raw = b"".join(b"\x00" + struct.pack(">%dH" % len(r), *r) for r in rows)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", len(rows[0]), len(rows), 16, 0, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw)))
        f.write(chunk(b"IEND", b""))


def frame_rows(i):
    """Frame i: a ramp of millimetres, 65535 (no return) in the first pixel, one reading nearer
    than 0.53 m and one farther than 4 m (both no return at the node's default range)."""
    rows = [[1000 + 10 * i + 7 * v + u for u in range(W)] for v in range(H)]
    rows[0][0] = 65535
    rows[1][1] = 300
    rows[2][2] = 4500
    return rows


def make_folder(root, bad_pose_line=None):
    data = os.path.join(root, "data")
    os.makedirs(data)
    with open(os.path.join(data, "camera-intrinsics.txt"), "w") as f:
        f.write("%g 0 %g\n0 %g %g\n0 0 1\n" % (K[0], K[2], K[1], K[3]))
    for i in range(3):
        write_png16(os.path.join(data, "frame-%06d.depth.png" % i), frame_rows(i))
        pose = "1 0 0 %g\n0 1 0 0\n0 0 1 0\n0 0 0 1\n" % (0.01 * i)
        if bad_pose_line is not None and i == 1:
            lines = pose.splitlines()
            lines[bad_pose_line - 1] = "0 1 zero 0"
            pose = "\n".join(lines) + "\n"
        with open(os.path.join(data, "frame-%06d.pose.txt" % i), "w") as f:
            f.write(pose)
    return root


def make_tum_folder(root):
    """A TUM RGB-D layout folder without intrinsics.txt: depth.txt and two 640x480 16-bit PNGs in
    1/5000 m (the size of the published calibrations, whose principal points must lie inside)."""
    os.makedirs(os.path.join(root, "depth"))
    with open(os.path.join(root, "depth.txt"), "w") as f:
        f.write("# depth maps\n# timestamp filename\n")
        for i in range(2):
            name = "depth/%d.png" % i
            write_png16(os.path.join(root, name), [[5000 + 5 * i] * 640 for _ in range(480)])
            f.write("%.6f %s\n" % (1305031102.0 + i / 30.0, name))
    return root


def start_node(ns, folder, *extra):
    # ~fx..~cy set to something else: the folder's own file must win.
    return subprocess.Popen(
        ["rosrun", "rig_drivers", "depth_camera", "__name:=depth_camera", "__ns:=" + ns,
         "_backend:=tum", "_tum_folder:=" + folder, "_triggered:=true",
         "_fx:=458.0", "_fy:=458.0", "_cx:=320.0", "_cy:=240.0"] + list(extra),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def first_info(ns, node):
    """The camera_info of the first triggered frame of the node started in namespace ns."""
    infos = []
    rospy.Subscriber(ns + "/camera_info", CameraInfo, infos.append, queue_size=10)
    try:
        rospy.wait_for_service(ns + "/depth_camera/trigger", timeout=30)
        trigger = rospy.ServiceProxy(ns + "/depth_camera/trigger", Trigger)
        time.sleep(1.0)  # the subscription connects
        deadline = time.time() + 10
        while time.time() < deadline and not infos:
            trigger()
            time.sleep(0.2)
    finally:
        node.terminate()
        node.wait(timeout=10)
    return infos[0] if infos else None


class DepthCameraFolder(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_depth_camera_folder")
        cls.tmp = tempfile.mkdtemp(prefix="dt_depth_camera_folder_")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_plays_a_seven_scenes_folder(self):
        folder = make_folder(os.path.join(self.tmp, "good"))
        lock = threading.Lock()
        images, infos = [], []

        def on_image(m):
            with lock:
                images.append(m)

        def on_info(m):
            with lock:
                infos.append(m)

        rospy.Subscriber("/seq7/image_rect", Image, on_image, queue_size=10)
        rospy.Subscriber("/seq7/camera_info", CameraInfo, on_info, queue_size=10)
        node = start_node("/seq7", folder)
        try:
            rospy.wait_for_service("/seq7/depth_camera/trigger", timeout=30)
            trigger = rospy.ServiceProxy("/seq7/depth_camera/trigger", Trigger)
            deadline = time.time() + 10
            while time.time() < deadline and rospy.get_published_topics("/seq7") == []:
                time.sleep(0.05)
            time.sleep(1.0)  # the subscriptions connect
            for _ in range(3):
                self.assertTrue(trigger().success)
            deadline = time.time() + 10
            while time.time() < deadline:
                with lock:
                    if len(images) >= 3 and len(infos) >= 3:
                        break
                time.sleep(0.05)
        finally:
            node.terminate()
            node.wait(timeout=10)
        with lock:
            self.assertEqual(len(images), 3)
            self.assertEqual(len(infos), 3)
            for i, (img, info) in enumerate(zip(images, infos)):
                self.assertEqual((img.width, img.height, img.encoding), (W, H, "16UC1"))
                self.assertEqual(img.header.frame_id, "camera_depth_optical_frame")
                self.assertAlmostEqual(img.header.stamp.to_sec(), 1.0 + i / 30.0, places=6)
                self.assertEqual(info.header.stamp, img.header.stamp)
                self.assertEqual((info.width, info.height), (W, H))
                self.assertEqual(list(info.K), [K[0], 0, K[2], 0, K[1], K[3], 0, 0, 1])
                fmt = (">" if img.is_bigendian else "<") + "%dH" % (W * H)
                got = struct.unpack(fmt, bytes(img.data))
                want = [v if 530 <= v <= 4000 else 0 for r in frame_rows(i) for v in r]
                self.assertEqual(list(got), want)

    def test_a_malformed_pose_file_is_named(self):
        folder = make_folder(os.path.join(self.tmp, "bad"), bad_pose_line=2)
        node = start_node("/seq7bad", folder)
        out, _ = node.communicate(timeout=30)
        self.assertNotEqual(node.returncode, 0, out)
        self.assertIn("frame-000001.pose.txt:2:", out)
        self.assertIn("'zero' is not a finite number", out)

    def test_a_tum_folder_named_for_a_camera_needs_its_calibration(self):
        folder = make_tum_folder(os.path.join(self.tmp, "rgbd_dataset_freiburg1_xyz"))
        node = start_node("/tumref", folder)
        out, _ = node.communicate(timeout=30)
        self.assertNotEqual(node.returncode, 0, out)
        self.assertIn("has no intrinsics file and looks like a TUM fr1 sequence", out)
        self.assertIn("set ~tum_camera fr1", out)

        info = first_info("/tumfr1", start_node("/tumfr1", folder, "_tum_camera:=fr1"))
        self.assertIsNotNone(info)
        self.assertEqual((info.width, info.height), (640, 480))
        self.assertEqual(list(info.K), [517.3, 0, 318.6, 0, 516.5, 255.3, 0, 0, 1])

        info = first_info("/tumpar", start_node("/tumpar", folder, "_tum_camera:=params"))
        self.assertIsNotNone(info)
        self.assertEqual(list(info.K), [458.0, 0, 320.0, 0, 458.0, 240.0, 0, 0, 1])

    def test_an_unknown_tum_camera_is_refused(self):
        folder = make_tum_folder(os.path.join(self.tmp, "plain"))
        node = start_node("/tumbad", folder, "_tum_camera:=fr4")
        out, _ = node.communicate(timeout=30)
        self.assertNotEqual(node.returncode, 0, out)
        self.assertIn("~tum_camera 'fr4' unknown", out)


if __name__ == "__main__":
    rostest.rosrun("rig_drivers", "depth_camera_folder", DepthCameraFolder)
