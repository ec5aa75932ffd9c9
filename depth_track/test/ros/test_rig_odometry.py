#!/usr/bin/env python3
"""rig_odometry on a real roscore: the truck's dead reckoning from rig_msgs/TruckRc, published as
nav_msgs/Odometry and tf, and what it does with bad readings.

Readings at 30 Hz with the speed demand 0.5 m/s straight ahead from the first one (the model's
lags start settled on the first demands), so the base moves 0.5 m/s exactly: x = 0.5 (t - t0).
Then a reading with a NaN speed (skipped: no odometry for it, and the next reading goes on from
the last good one), and a reading back in time (a looped bag: the odometry starts again at the
identity)."""
import math
import sys
import threading
import time
import unittest

import rospy
import rostest
from nav_msgs.msg import Odometry
from rig_msgs.msg import TruckRc
from tf2_msgs.msg import TFMessage

T0 = 100.0
DT = 1.0 / 30.0


class RigOdometry(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_rig_odometry")
        cls.lock = threading.Lock()
        cls.odom = []
        cls.tf = []
        rospy.Subscriber("/rig_odometry/odom", Odometry, cls.on_odom, queue_size=100)
        cls.pub = rospy.Publisher("/truck_rc", TruckRc, queue_size=100)
        rospy.Subscriber("/tf", TFMessage, cls.on_tf, queue_size=100)
        deadline = time.time() + 20.0
        while cls.pub.get_num_connections() == 0 and time.time() < deadline:
            time.sleep(0.05)

    @classmethod
    def on_odom(cls, m):
        with cls.lock:
            cls.odom.append(m)

    @classmethod
    def on_tf(cls, m):
        with cls.lock:
            cls.tf += [t for t in m.transforms if t.child_frame_id == "rig_base_link"]

    def send(self, stamp, speed, steering=0.0):
        r = TruckRc()
        r.header.stamp = rospy.Time.from_sec(stamp)
        r.speed_mps = speed
        r.steering = steering
        r.signal_ok = True
        self.pub.publish(r)
        time.sleep(0.01)

    def wait_for(self, n, timeout=10.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                if len(self.odom) >= n:
                    return list(self.odom)
            time.sleep(0.02)
        with self.lock:
            return list(self.odom)

    def test_dead_reckoning_and_bad_readings(self):
        self.assertGreater(self.pub.get_num_connections(), 0, "rig_odometry never subscribed")
        for k in range(31):
            self.send(T0 + k * DT, 0.5)
        got = self.wait_for(31)
        self.assertEqual(len(got), 31)
        for k, m in enumerate(got):
            self.assertAlmostEqual(m.header.stamp.to_sec(), T0 + k * DT, places=6)
            self.assertEqual(m.header.frame_id, "rig_odom")
            self.assertEqual(m.child_frame_id, "rig_base_link")
            self.assertAlmostEqual(m.pose.pose.position.x, 0.5 * k * DT, places=6)
            self.assertAlmostEqual(m.pose.pose.position.y, 0.0, places=9)
            self.assertAlmostEqual(m.twist.twist.linear.x, 0.5, places=9)
        # The same poses as tf rig_odom -> rig_base_link, one per reading.
        with self.lock:
            tf = list(self.tf)
        self.assertEqual(len(tf), 31)
        self.assertEqual(tf[-1].header.frame_id, "rig_odom")
        self.assertAlmostEqual(tf[-1].header.stamp.to_sec(), T0 + 30 * DT, places=6)
        self.assertAlmostEqual(tf[-1].transform.translation.x, 0.5, places=6)

        # A NaN speed: skipped, no odometry; the next reading goes on from the last good one.
        self.send(T0 + 31 * DT, float("nan"))
        self.send(T0 + 32 * DT, 0.5)
        got = self.wait_for(32)
        self.assertEqual(len(got), 32, "the NaN reading must give no odometry")
        self.assertAlmostEqual(got[-1].header.stamp.to_sec(), T0 + 32 * DT, places=6)
        self.assertAlmostEqual(got[-1].pose.pose.position.x, 0.5 * 32 * DT, places=6)
        self.assertTrue(all(math.isfinite(m.pose.pose.position.x) for m in got))

        # Back in time (a looped bag): the odometry starts again at the identity there.
        self.send(T0 - 50.0, 0.5)
        self.send(T0 - 50.0 + DT, 0.5)
        got = self.wait_for(34)
        self.assertEqual(len(got), 34)
        self.assertAlmostEqual(got[-2].pose.pose.position.x, 0.0, places=9)
        self.assertAlmostEqual(got[-1].pose.pose.position.x, 0.5 * DT, places=6)


if __name__ == "__main__":
    rostest.rosrun("depth_track", "rig_odometry_node", RigOdometry, sys.argv)
