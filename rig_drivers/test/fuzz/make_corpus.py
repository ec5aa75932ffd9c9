#!/usr/bin/env python3
"""Seed corpus of the rig fuzz targets from recorded frames.

Reads the /raw_frames topic (rig_msgs/RawFrame, both directions) of scenario bags and writes
  <out>/codec/     byte streams as a link carried them (one board, one direction, a window of
                   consecutive frames), in the input layout of test/protocol/fuzz_codec.cpp
  <out>/firmware/  the host's commands to the boards with the recorded time between them, in the
                   input layout of test/protocol/fuzz_firmware.cpp
Message types the bags do not contain (the simulator never sends vers, para, ping, stop, reset,
end) get one small synthetic seed each, named synth_*, so that no command starts unseeded.

  make_corpus.py [--out DIR] BAG...        (default DIR: rig_drivers/test/fuzz/corpus)
  make_corpus.py --generate [--out DIR]    makes the bags first, see below

--generate runs bags/generate_bags.sh for SCENARIOS (default: every scenario) with MAX_FRAMES=150
into a temporary folder (needs the workspace built), then extracts from those bags. The committed
corpus was made that way. Output is deterministic: the same bags give the same files.
"""
import argparse
import binascii
import os
import shutil
import struct
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
DEFAULT_OUT = os.path.join(HERE, "corpus")

WINDOW = 6            # frames per codec seed (a TrackState window is ~200 bytes)
MAX_CODEC_SEEDS = 6   # per bag, board and direction
FW_WINDOW = 16        # commands per firmware seed after the board's set-up commands
MAX_FW_SEEDS = 4      # per bag
TICK_MS = 10          # firmware seeds: loop tick
MAX_GAP_S = 3.0       # longest pause kept between two commands (fast homing needs ~2.5 s)
SETUP_IDS = {0x01, 0x02, 0x03}  # init, mode, start: replayed before every firmware window
BUDGET_S = 10.0       # board time fuzz_firmware gives one input (kMaxBoardTimeUs)
# firmware header: 20-tooth pulley, TICK_MS ticks, carriage 2 % along the track (short homing),
# near sensor where configured
HEADER = bytes([(TICK_MS - 1) << 2, 0x00, 0x05, 0x00])


def read_frames(path):
    """[(t, board, outgoing, bytes)] of a bag's /raw_frames, in bag order."""
    import rosbag  # python3-rosbag; imported here so --help works without ROS
    out = []
    with rosbag.Bag(path) as bag:
        for _, msg, t in bag.read_messages(topics=["/raw_frames"]):
            data = bytes(msg.bytes)
            if len(data) < 12 or data[0] != 0xA5 or data[1] != 0x5A:
                raise ValueError("%s: /raw_frames message at %.3f s is not a frame" % (path, t.to_sec()))
            out.append((t.to_sec(), msg.board, bool(msg.outgoing), data))
    return out


def codec_seeds(name, frames):
    """Windows of consecutive frames per (board, direction); distinct id sequences first."""
    seeds = {}
    streams = {}
    for _, board, outgoing, data in frames:
        streams.setdefault((board, outgoing), []).append(data)
    for (board, outgoing), fr in sorted(streams.items()):
        windows = [fr[i:i + WINDOW] for i in range(0, max(1, len(fr) - WINDOW + 1), WINDOW)]
        chosen, seen = [], set()
        for w in windows:  # one window per distinct message-id sequence ...
            sig = tuple(f[5] for f in w)
            if sig not in seen:
                seen.add(sig)
                chosen.append(w)
        step = max(1, len(windows) // MAX_CODEC_SEEDS)
        for w in windows[::step]:  # ... then evenly spaced ones
            if len(chosen) >= MAX_CODEC_SEEDS:
                break
            if w not in chosen:
                chosen.append(w)
        for n, w in enumerate(chosen[:MAX_CODEC_SEEDS]):
            stream = b"".join(w)
            # header: chunk sizes from the frame lengths (k of them), CRC repair on every other seed
            k = n % 4
            chunks = bytes((len(w[j % len(w)]) - 1 + j) % 256 for j in range(k))
            header = bytes([k | (8 if n % 2 else 0)]) + chunks
            tag = "%s_b%d_%s_%d" % (name, board, "out" if outgoing else "in", n)
            seeds[tag] = header + stream
    return seeds


def ticks(gap_s, cap_s=MAX_GAP_S):
    """Time records for a pause: op 0x40 | (n - 1) lets n ticks pass, n <= 64."""
    n = int(round(min(gap_s, cap_s) * 1000.0 / TICK_MS))
    out = b""
    while n > 0:
        m = min(n, 64)
        out += bytes([0x40 | (m - 1)])
        n -= m
    return out


def command_record(data):
    board, msg_id, plen = data[4], data[5], data[2]
    return bytes([board & 3, msg_id, plen]) + data[10:10 + plen]


def firmware_seeds(name, frames):
    """The recorded host commands, set-up first, then windows of the rest with their pauses."""
    cmds = [(t, data) for t, _, outgoing, data in frames if outgoing]
    if not cmds:
        return {}
    setup = [c for c in cmds if c[1][5] in SETUP_IDS]
    rest = [c for c in cmds if c[1][5] not in SETUP_IDS]
    header = HEADER
    windows = [rest[i:i + FW_WINDOW] for i in range(0, len(rest), FW_WINDOW)] or [[]]
    step = max(1, len(windows) // MAX_FW_SEEDS)
    seeds = {}
    for n, w in enumerate(windows[::step][:MAX_FW_SEEDS]):
        body, prev = b"", None
        for t, data in setup + w:
            if prev is not None:
                body += ticks(t - prev)
            body += command_record(data)
            prev = t
        body += ticks(BUDGET_S, BUDGET_S)  # the rest of the board time an input gets
        seeds["%s_%d" % (name, n)] = header + body
    return seeds


def frame(board, msg_id, seq, payload=b""):
    body = struct.pack("<BBBBI", len(payload), 1, board, msg_id, seq) + payload
    return b"\xa5\x5a" + body + struct.pack("<H", binascii.crc_hqx(body, 0xFFFF))


def synthetic_seeds(seen_ids):
    """One seed per message id the bags lack (codec: the frame; firmware: the command)."""
    name16 = lambda s: s.encode().ljust(16, b"\0")
    codec = {
        0x04: frame(1, 0x04, 1), 0x05: frame(1, 0x05, 2), 0x06: frame(1, 0x06, 3),
        0x07: frame(2, 0x07, 4), 0x08: frame(3, 0x08, 5),
        0x12: frame(1, 0x12, 6, struct.pack("<I", 123456)),
        0x84: frame(1, 0x84, 7, bytes([1, 0, 0, 1]) + name16("TrackDRV")),
        0x85: frame(2, 0x85, 8, struct.pack("<BBiB", 0, 8, -4000, 0xFE) + name16("pitch_min_deg")),
        0x86: frame(3, 0x86, 9, struct.pack("<II", 123456, 3000)),
    }
    seeds = {}
    for msg_id, f in sorted(codec.items()):
        if msg_id not in seen_ids:
            seeds[("codec", "synth_%02x" % msg_id)] = b"\x00" + f
    move = lambda um, mm_s: bytes([0x01, 0x10, 9]) + struct.pack("<iBHH", um, 0, mm_s, 0)
    estop_on, estop_off = bytes([0x89, 128, 133, 200]), bytes([0x88, 128, 133, 200])
    # Features the recorded runs never reach: reports, stop/reset/end, the near end-of-track
    # sensor (placed 60 mm short of the configured track, header byte 3), the e-stop.
    fw = {
        "synth_reports": HEADER + bytes([0x00, 0x07, 0, 0x00, 0x08, 0, 0x00, 0x12, 4]) +
        struct.pack("<I", 42),
        "synth_stop_reset_end": HEADER + bytes([0x00, 0x01, 0]) + ticks(1.0) +
        move(1000000, 0) + ticks(0.5) + bytes([0x00, 0x04, 0]) + ticks(0.2) +
        bytes([0x00, 0x05, 0, 0x00, 0x06, 0]),
        "synth_end_of_track": HEADER[:3] + bytes([0xC4]) + bytes([0x01, 0x01, 0]) + ticks(1.0) +
        move(1200000, 300) + ticks(BUDGET_S, BUDGET_S),
        "synth_estop": HEADER + bytes([0x01, 0x01, 0]) + ticks(1.0) + move(600000, 300) +
        ticks(0.5) + estop_on + ticks(0.2) + bytes([0x01, 0x01, 0]) + estop_off +
        bytes([0x01, 0x05, 0, 0x01, 0x01, 0]) + ticks(1.0),
    }
    for tag, data in fw.items():
        seeds[("firmware", tag)] = data
    return seeds


def write(out, seeds):
    for kind in ("codec", "firmware"):
        d = os.path.join(out, kind)
        if os.path.isdir(d):
            shutil.rmtree(d)
        os.makedirs(d)
    total = 0
    for (kind, tag), data in sorted(seeds.items()):
        with open(os.path.join(out, kind, tag), "wb") as f:
            f.write(data)
        total += len(data)
    return total


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bags", nargs="*", help="scenario bags with /raw_frames")
    ap.add_argument("--out", default=DEFAULT_OUT, help="corpus folder (default %(default)s)")
    ap.add_argument("--generate", action="store_true",
                    help="make the bags with bags/generate_bags.sh first (MAX_FRAMES=150)")
    ap.add_argument("--scenarios", nargs="*", default=[],
                    help="with --generate: scenario names (default: all)")
    args = ap.parse_args()
    tmp = None
    bags = list(args.bags)
    if args.generate:
        tmp = tempfile.mkdtemp(prefix="rig_corpus_bags_")
        env = dict(os.environ, MAX_FRAMES="150", COMPRESSION="lz4")
        subprocess.run([os.path.join(ROOT, "bags", "generate_bags.sh"), tmp] + args.scenarios,
                       check=True, env=env)
        bags += sorted(os.path.join(tmp, f) for f in os.listdir(tmp) if f.endswith(".bag"))
    if not bags:
        ap.error("no bags given (pass BAG... or --generate)")
    seeds, seen_ids = {}, set()
    try:
        for path in bags:
            name = os.path.splitext(os.path.basename(path))[0]
            frames = read_frames(path)
            if not frames:
                print("make_corpus.py: %s has no /raw_frames, skipped" % path, file=sys.stderr)
                continue
            seen_ids.update(f[3][5] for f in frames)
            for tag, data in codec_seeds(name, frames).items():
                seeds[("codec", tag)] = data
            for tag, data in firmware_seeds(name, frames).items():
                seeds[("firmware", tag)] = data
    finally:
        if tmp:
            shutil.rmtree(tmp)
    seeds.update(synthetic_seeds(seen_ids))
    total = write(args.out, seeds)
    n_codec = sum(1 for k in seeds if k[0] == "codec")
    print("make_corpus.py: %d codec + %d firmware seeds, %d bytes, in %s"
          % (n_codec, len(seeds) - n_codec, total, args.out))


if __name__ == "__main__":
    main()
