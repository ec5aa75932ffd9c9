#!/usr/bin/env python3
"""Runs a rig board's firmware image in qemu-system-avr and offers its serial port as a
pseudo-terminal, so the host drivers connect to it exactly as to a board on USB serial.

    rosrun rig_drivers emulated_board.py --image track_drv_mega2560_emu --link /tmp/rig_emu/track
    rig_drivers/scripts/emulated_board.py --elf <path/to/image.elf> --link /tmp/rig_emu/track

qemu emulates an Arduino Mega 2560 (-machine mega2560) whose USART0 is relayed to a new
pseudo-terminal; --link is a symlink to it (pass it as the driver's ~port). The relay can put
faults on the line, for tests of the drivers' recovery:

  - garbage: N pseudo-random bytes (sync pairs and plausible lengths among them) inserted into
    the board-to-host stream, inside a frame (after its fifth byte), or sent to the board;
  - corruption: one payload byte of the next board frame inverted, so its checksum fails.

Started by roslaunch (a __name:= argument), it serves these as std_srvs/Trigger services
~inject_garbage, ~inject_host_garbage and ~corrupt_next_frame (~garbage_bytes, default 100);
run alone, SIGUSR1 injects garbage into the board-to-host stream. It stops qemu on SIGINT/SIGTERM
or when qemu exits, and removes the link.
"""
import argparse
import os
import random
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tty

SYNC = b"\xa5\x5a"


class LineTap:
    """Relay state: faults armed by the services, applied by the relay loop."""

    def __init__(self, garbage_bytes, seed=7):
        self.lock = threading.Lock()
        self.garbage_bytes = garbage_bytes
        self.rng = random.Random(seed)
        self.garbage_to_host = False
        self.garbage_to_board = False
        self.corrupt = False
        self.done = threading.Condition(self.lock)
        self.events = 0

    def garbage(self):
        out = bytearray(self.rng.randrange(256) for _ in range(self.garbage_bytes))
        # A few false starts: sync pairs followed by a plausible header, so the decoder has to
        # reject candidates inside the garbage too, not only skip bytes that are not sync.
        for k in range(0, max(0, len(out) - 4), 25):
            out[k:k + 4] = SYNC + bytes([self.rng.randrange(64), 1])
        return bytes(out)

    def arm(self, what):
        with self.lock:
            setattr(self, what, True)
            start = self.events
            # The relay applies it with the next board bytes; wait until it has.
            while self.events == start:
                if not self.done.wait(timeout=30.0):
                    setattr(self, what, False)
                    return False
            return True

    def applied(self):
        self.events += 1
        self.done.notify_all()


class BoardToHost:
    """Forwards board bytes to the host, applying armed faults at frame positions."""

    def __init__(self, tap):
        self.tap = tap
        self.prev = 0  # previous byte, to spot sync pairs
        self.since_sync = -1  # bytes of the current frame seen after its sync pair

    def process(self, data):
        out = bytearray()
        with self.tap.lock:
            for b in data:
                if self.prev == SYNC[0] and b == SYNC[1]:
                    self.since_sync = 0
                elif self.since_sync >= 0:
                    self.since_sync += 1
                self.prev = b
                if self.tap.corrupt and self.since_sync == 10:  # a payload byte of the frame
                    b ^= 0xFF
                    self.tap.corrupt = False
                    self.tap.applied()
                out.append(b)
                if self.tap.garbage_to_host and self.since_sync == 3:  # inside a frame
                    out += self.tap.garbage()
                    self.tap.garbage_to_host = False
                    self.tap.applied()
        return bytes(out)


def write_all(fd, data):
    while data:
        try:
            n = os.write(fd, data)
            data = data[n:]
        except BlockingIOError:
            return  # nobody reads the terminal: drop, as a board's USB-serial chip would
        except OSError:
            return


def start_qemu(qemu, elf, sock_path, log):
    cmd = [qemu, "-machine", "mega2560", "-bios", elf, "-display", "none", "-monitor", "none",
           "-chardev", "socket,id=link,path=%s,server=on,wait=on" % sock_path,
           "-serial", "chardev:link"]
    proc = subprocess.Popen(cmd, stdout=log, stderr=log, stdin=subprocess.DEVNULL)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    for _ in range(600):
        if proc.poll() is not None:
            raise RuntimeError("%s exited with %d" % (qemu, proc.returncode))
        try:
            sock.connect(sock_path)
            return proc, sock
        except OSError:
            time.sleep(0.05)
    proc.kill()
    raise RuntimeError("%s did not open its serial socket" % qemu)


def relay(sock, master, tap, qemu_proc, stop, baud):
    """Moves bytes both ways until qemu exits or `stop` is set. Host bytes reach the board no
    faster than the line's baud rate (10 bits a byte): the emulated USART has no baud timing, and
    a burst at memory speed would overrun any board's receive buffer where the wire never could."""
    to_host = BoardToHost(tap)
    to_board = bytearray()
    budget, last = 0.0, time.monotonic()
    while not stop.is_set() and qemu_proc.poll() is None:
        r, _, _ = select.select([sock, master], [], [], 0.001 if to_board else 0.1)
        if sock in r:
            data = sock.recv(4096)
            if not data:
                break
            write_all(master, to_host.process(data))
        if master in r:
            try:
                to_board += os.read(master, 4096)
            except OSError:
                pass
        with tap.lock:
            if tap.garbage_to_board:
                to_board = bytearray(tap.garbage()) + to_board
                tap.garbage_to_board = False
                tap.applied()
        now = time.monotonic()
        budget = min(budget + (now - last) * baud / 10.0, 64.0) if to_board else 0.0
        last = now
        n = int(budget)
        if n > 0:
            sock.sendall(bytes(to_board[:n]))
            del to_board[:n]
            budget -= n


def serve_ros(tap):
    import rospy
    from std_srvs.srv import Trigger, TriggerResponse

    rospy.init_node("emulated_board", disable_signals=True)
    tap.garbage_bytes = int(rospy.get_param("~garbage_bytes", tap.garbage_bytes))

    def service(what, text):
        def handle(_):
            ok = tap.arm(what)
            return TriggerResponse(success=ok, message=text if ok else "not applied within 30 s")
        return handle

    n = tap.garbage_bytes
    return [
        rospy.Service("~inject_garbage", Trigger,
                      service("garbage_to_host", "%d garbage bytes inside a board frame" % n)),
        rospy.Service("~inject_host_garbage", Trigger,
                      service("garbage_to_board", "%d garbage bytes sent to the board" % n)),
        rospy.Service("~corrupt_next_frame", Trigger,
                      service("corrupt", "one payload byte of a board frame inverted")),
    ]


def find_image(name):
    """The built image `name`.elf of the workspace (catkin_make writes them to
    devel/share/rig_drivers/firmware), or "" when there is none."""
    try:
        from catkin.find_in_workspaces import find_in_workspaces
    except ImportError:
        return ""
    found = find_in_workspaces(search_dirs=["share"], project="rig_drivers",
                               path="firmware/%s.elf" % name, first_match_only=True)
    return found[0] if found else ""


def main():
    argv = [a for a in sys.argv[1:] if not a.startswith("__")]
    under_roslaunch = any(a.startswith("__name:=") for a in sys.argv[1:])
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--elf", help="firmware image file (an *_mega2560_emu.elf)")
    which.add_argument("--image", help="image name, looked up in the catkin workspace's "
                       "share/rig_drivers/firmware (e.g. track_drv_mega2560_emu)")
    p.add_argument("--link", required=True, help="symlink to create for the pseudo-terminal")
    p.add_argument("--qemu", default="qemu-system-avr")
    p.add_argument("--garbage-bytes", type=int, default=100)
    p.add_argument("--baud", type=int, default=115200, help="pace of the host's bytes to the board")
    p.add_argument("--log", help="keep qemu's output in this file (default: shown only when "
                   "qemu fails)")
    args = p.parse_args(argv)

    if args.image:
        args.elf = find_image(args.image)
    if shutil.which(args.qemu) is None:
        sys.exit("emulated_board.py: %s not found: install qemu-system-misc" % args.qemu)
    if not args.elf or not os.path.isfile(args.elf):
        sys.exit("emulated_board.py: no firmware image %s (built by catkin_make, or by "
                 "rig_drivers/scripts/build_firmware.sh <dir>)" % (args.elf or args.image))
    link_dir = os.path.dirname(os.path.abspath(args.link))
    made_dir = not os.path.isdir(link_dir)
    os.makedirs(link_dir, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix="rig_emu_")
    log_path = args.log or os.path.join(tmp, "qemu.log")
    log = open(log_path, "w")
    try:
        qemu_proc, sock = start_qemu(args.qemu, args.elf, os.path.join(tmp, "link.sock"), log)
    except RuntimeError as e:
        log.close()
        sys.stderr.write(open(log_path).read())
        shutil.rmtree(tmp, ignore_errors=True)
        sys.exit("emulated_board.py: %s" % e)

    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    os.set_blocking(master, False)
    if os.path.lexists(args.link):
        os.unlink(args.link)
    os.symlink(os.ttyname(slave), args.link)
    print("emulated_board.py: %s on %s (%s)" % (os.path.basename(args.elf), args.link,
                                                os.ttyname(slave)), flush=True)

    tap = LineTap(args.garbage_bytes)
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    signal.signal(signal.SIGUSR1,
                  lambda *_: threading.Thread(target=tap.arm, args=("garbage_to_host",)).start())
    services = serve_ros(tap) if under_roslaunch else []
    try:
        relay(sock, master, tap, qemu_proc, stop, args.baud)
    finally:
        for s in services:
            s.shutdown()
        qemu_proc.terminate()
        try:
            qemu_proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            qemu_proc.kill()
        if os.path.islink(args.link):
            os.unlink(args.link)
        if made_dir:
            try:
                os.rmdir(link_dir)
            except OSError:
                pass
        log.close()
        if qemu_proc.returncode not in (0, -signal.SIGTERM, -signal.SIGKILL) and not args.log:
            sys.stderr.write(open(log_path).read())
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if stop.is_set() else 1


if __name__ == "__main__":
    sys.exit(main())
