#!/usr/bin/env python3
"""ROS-level reliability runs of endo_stereo (RELIABILITY.md: bad input, floods, soak), with a real master.

Modes (the node under test is started, watched and restarted by this driver):
  soak       closed loop: publish a stereo pair, wait for its disparity, repeat --frames times
             (as fast as the node takes them); a second thread hammers dynamic_reconfigure with
             random (valid and invalid) values; RSS of the node sampled at start, after warm-up,
             every 1000 frames and at the end.
  overload   open loop: publish pairs at --rate Hz for --seconds (faster than the node works);
             checks bounded memory, that every pair is accounted for (processed + dropped +
             rejected = received, from the node's diagnostics), newest-first processing and
             output stamps that only increase.
  inventory  every entry of the bad-input inventory, each followed by a good pair, against
             --target endo_stereo or stereo_image_proc (Debian's; run scripts/stereo_image_proc_env.sh
             first): whether the node survived, what it logged, whether it published something
             for the bad input, whether the next good pair was processed. Writes JSON and a
             Markdown table.

Run with /usr/bin/python3 (the ROS modules), a roscore on $ROS_MASTER_URI, and the workspace
sourced. scripts/soak.sh and scripts/inventory.sh do all of that.
"""
import argparse
import json
import os
import random
import signal
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import rospy
from rosgraph_msgs.msg import Clock, Log
from sensor_msgs.msg import CameraInfo, Image

NS = "/stereo"
W, H = 320, 240
F_PX = 300.0
BASELINE_M = 0.005
SHIFT_PX = 8


# ------------------------------------------------------------------------------------------------
# Node under test
# ------------------------------------------------------------------------------------------------
class NodeProcess:
    """The node under test as a child process (so its RSS, exit status and stderr are ours)."""

    def __init__(self, target, log_dir, node_exe=None, params=None):
        self.target = target
        self.log_dir = log_dir
        self.node_exe = node_exe
        self.params = dict(params or {})
        if target == "endo_stereo":
            # The driver sends one synthetic pair over and over, a frozen camera by the node's
            # definition (~freeze_frames): the check is off unless a --param turns it on.
            self.params.setdefault("freeze_frames", 0)
        self.proc = None
        self.log_path = None
        self.starts = 0
        if target == "endo_stereo":
            self.name = NS + "/endo_stereo"
        else:
            self.name = NS + "/stereo_image_proc"

    def start(self, extra_params=None):
        self.starts += 1
        params = dict(self.params)
        params.update(extra_params or {})
        # Fresh private parameters for every start (a case may have left some behind).
        try:
            rospy.delete_param(self.name)
        except KeyError:
            pass
        for k, v in params.items():
            rospy.set_param(self.name + "/" + k, v)
        if self.target == "endo_stereo":
            cmd = [self.node_exe, "__ns:=" + NS, "__name:=endo_stereo"]
        else:
            cmd = ["/usr/lib/stereo_image_proc/stereo_image_proc", "__ns:=" + NS,
                   "__name:=stereo_image_proc"]
        self.log_path = os.path.join(self.log_dir, "%s_%d.log" % (self.target, self.starts))
        self.log = open(self.log_path, "w")
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT)
        return self.proc.pid

    def alive(self):
        return self.proc is not None and self.proc.poll() is None

    def exit_description(self):
        if self.proc is None:
            return "not started"
        rc = self.proc.poll()
        if rc is None:
            return "running"
        if rc < 0:
            return "killed by %s" % signal.Signals(-rc).name
        return "exit code %d" % rc

    def last_log_lines(self, n=3, pattern=None):
        try:
            with open(self.log_path, errors="replace") as f:
                lines = [l.strip() for l in f if l.strip()]
        except OSError:
            return []
        if pattern:
            lines = [l for l in lines if any(p in l for p in pattern)]
        return lines[-n:]

    def rss_kb(self):
        try:
            with open("/proc/%d/status" % self.proc.pid) as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        return int(line.split()[1])
        except OSError:
            pass
        return -1

    def stop(self):
        if self.alive():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None:
            self.log.close()


# ------------------------------------------------------------------------------------------------
# Messages
# ------------------------------------------------------------------------------------------------
def texture(w, h, seed):
    rng = np.random.RandomState(seed)
    t = rng.randint(0, 256, size=(h, w)).astype(np.float32)
    # A 3x3 box blur keeps the texture matchable at every window size.
    p = np.pad(t, 1, mode="edge")
    t = sum(p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)) / 9.0
    return t.astype(np.uint8)


class PairMaker:
    """Good stereo pairs (right(x) = left(x + SHIFT_PX)) and their camera_info, cached by size."""

    def __init__(self):
        self.cache = {}

    def images(self, w, h, encoding="bgr8"):
        key = (w, h, encoding)
        if key not in self.cache:
            wide = texture(w + SHIFT_PX, h, 11)
            left, right = wide[:, :w], wide[:, SHIFT_PX:SHIFT_PX + w]
            if encoding == "bgr8":
                left = np.ascontiguousarray(np.repeat(left[:, :, None], 3, axis=2))
                right = np.ascontiguousarray(np.repeat(right[:, :, None], 3, axis=2))
            self.cache[key] = (left.tobytes(), right.tobytes())
        return self.cache[key]


def make_image(stamp, frame_id, w, h, encoding, data, step=None):
    m = Image()
    m.header.stamp = stamp
    m.header.frame_id = frame_id
    m.width, m.height = w, h
    m.encoding = encoding
    m.is_bigendian = 0
    bpp = {"mono8": 1, "bgr8": 3, "rgb8": 3, "mono16": 2, "32FC1": 4, "64FC1": 8,
           "bayer_rggb8": 1}.get(encoding, 1)
    m.step = step if step is not None else w * bpp
    m.data = data
    return m


def make_info(stamp, frame_id, w, h, tx=0.0, f=F_PX, k_override=None):
    c = CameraInfo()
    c.header.stamp = stamp
    c.header.frame_id = frame_id
    c.width, c.height = w, h
    c.distortion_model = "plumb_bob"
    c.D = [0.0] * 5
    c.K = [f, 0, w / 2.0, 0, f, h / 2.0, 0, 0, 1] if k_override is None else k_override
    c.R = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    c.P = [f, 0, w / 2.0, tx, 0, f, h / 2.0, 0, 0, 0, 1, 0]
    return c


class Rig:
    """Publishers of the stereo inputs and counters of the outputs (raw messages, no parsing)."""

    def __init__(self, node_name):
        self.node_name = node_name
        self.pub = {
            "li": rospy.Publisher(NS + "/left/image_raw", Image, queue_size=50),
            "ri": rospy.Publisher(NS + "/right/image_raw", Image, queue_size=50),
            "lc": rospy.Publisher(NS + "/left/camera_info", CameraInfo, queue_size=50),
            "rc": rospy.Publisher(NS + "/right/camera_info", CameraInfo, queue_size=50),
        }
        self.lock = threading.Condition()
        self.disparity_stamps = []  # (stamp as float, wall arrival)
        self.points = 0
        self.logs = []  # (wall time, level, text) from the node under test
        self.diag = {}
        self.subs = [
            rospy.Subscriber(NS + "/disparity", rospy.AnyMsg, self._disparity, queue_size=100),
            rospy.Subscriber(NS + "/points2", rospy.AnyMsg, self._points, queue_size=100),
            rospy.Subscriber("/rosout_agg", Log, self._log, queue_size=1000),
            rospy.Subscriber("/diagnostics", rospy.AnyMsg, self._diag, queue_size=10),
        ]
        self.pairs = PairMaker()

    @staticmethod
    def _stamp_of(raw):
        # Every message here starts with a std_msgs/Header: seq (u32), stamp secs, nsecs (u32).
        _, secs, nsecs = struct.unpack_from("<III", raw._buff, 0)
        return secs + nsecs * 1e-9

    def _disparity(self, raw):
        with self.lock:
            self.disparity_stamps.append((self._stamp_of(raw), time.time()))
            self.lock.notify_all()

    def _points(self, raw):
        with self.lock:
            self.points += 1

    def _log(self, msg):
        if msg.name == self.node_name and msg.level >= Log.WARN:
            with self.lock:
                self.logs.append((time.time(), msg.level, msg.msg))

    def _diag(self, raw):
        from diagnostic_msgs.msg import DiagnosticArray
        arr = DiagnosticArray()
        arr.deserialize(raw._buff)
        for st in arr.status:
            if "endo_stereo" in st.name or "reconstruction" in st.name:
                with self.lock:
                    self.diag = {kv.key: kv.value for kv in st.values}

    def wait_connected(self, timeout=20.0):
        end = time.time() + timeout
        while time.time() < end and not rospy.is_shutdown():
            if all(p.get_num_connections() > 0 for p in self.pub.values()):
                return True
            time.sleep(0.05)
        return False

    def publish(self, left, right, linfo=None, rinfo=None):
        if linfo is not None:
            self.pub["lc"].publish(linfo)
        if rinfo is not None:
            self.pub["rc"].publish(rinfo)
        if left is not None:
            self.pub["li"].publish(left)
        if right is not None:
            self.pub["ri"].publish(right)

    def publish_good(self, t, w=W, h=H, encoding="bgr8", baseline=BASELINE_M):
        stamp = rospy.Time.from_sec(t)
        ld, rd = self.pairs.images(w, h, encoding)
        self.publish(make_image(stamp, "stereo_optical", w, h, encoding, ld),
                     make_image(stamp, "stereo_optical", w, h, encoding, rd),
                     make_info(stamp, "stereo_optical", w, h),
                     make_info(stamp, "stereo_optical", w, h, tx=-F_PX * baseline))

    def outputs_since(self, wall_t):
        with self.lock:
            return [s for s, a in self.disparity_stamps if a >= wall_t]

    def wait_output(self, stamp_s, timeout):
        end = time.time() + timeout
        with self.lock:
            while time.time() < end and not rospy.is_shutdown():
                if any(abs(s - stamp_s) < 1e-6 for s, _ in self.disparity_stamps[-50:]):
                    return True
                self.lock.wait(0.05)
        return False

    def logs_since(self, wall_t):
        with self.lock:
            return [m for t, _, m in self.logs if t >= wall_t]


# ------------------------------------------------------------------------------------------------
# Reconfigure hammer
# ------------------------------------------------------------------------------------------------
class Hammer(threading.Thread):
    """Random dynamic_reconfigure updates as fast as the server answers (valid and invalid)."""

    def __init__(self, server, period_s=0.0, seed=6):
        super().__init__(daemon=True)
        self.server = server
        self.period_s = period_s
        self.rng = random.Random(seed)
        self.stop_flag = threading.Event()
        self.calls = 0
        self.errors = 0

    def random_config(self):
        r = self.rng
        c = {}
        # Ranges kept small enough for 320x240 frames to stay fast; about one update in four is
        # invalid for the pipeline (even window, min > max, window_max < window_min).
        lo = r.randint(0, 6)
        c["matcher_min_disparity"] = lo
        c["matcher_max_disparity"] = r.choice([lo + r.randint(4, 24), max(0, lo - 2)])
        c["matcher_window_min_px"] = r.choice([3, 5, 7, 9, 4])
        c["matcher_window_step_px"] = r.choice([2, 4, 6, 3])
        c["matcher_window_max_px"] = r.choice([9, 15, 21, 5])
        c["matcher_delta_min"] = r.uniform(0.0, 0.5)
        c["matcher_gamma_min"] = r.uniform(0.0, 3.0)
        c["matcher_epsilon_px"] = r.uniform(0.5, 8.0)
        c["matcher_subpixel"] = r.random() < 0.5
        c["filter_remove_outliers"] = r.random() < 0.5
        c["filter_fill_holes"] = r.random() < 0.5
        c["temporal_enabled"] = r.random() < 0.7
        c["temporal_prior_radius_px"] = r.randint(1, 8)
        c["output_point_cloud"] = r.random() < 0.8
        c["output_fused"] = r.random() < 0.3
        c["output_coverage"] = r.random() < 0.3
        return c

    def run(self):
        import dynamic_reconfigure.client
        try:
            client = dynamic_reconfigure.client.Client(self.server, timeout=30)
        except Exception as ex:  # noqa: BLE001 - reported, the run goes on without the hammer
            print("[driver] reconfigure client failed: %s" % ex, flush=True)
            return
        while not self.stop_flag.is_set() and not rospy.is_shutdown():
            try:
                client.update_configuration(self.random_config())
                self.calls += 1
            except Exception:  # noqa: BLE001 - a refused or timed-out update is counted
                self.errors += 1
            if self.period_s > 0:
                time.sleep(self.period_s)


# ------------------------------------------------------------------------------------------------
# soak and overload
# ------------------------------------------------------------------------------------------------
def soak(args, node, rig):
    node.start()
    if not rig.wait_connected():
        print("[driver] node did not subscribe (lazy subscription needs our subscribers)")
        return 1
    hammer = Hammer(node.name) if args.hammer else None
    t = 1000.0
    processed = lost = 0
    rss = {}
    t0 = time.time()
    # Warm-up pair before the hammer starts and before the first RSS sample.
    for _ in range(3):
        rig.publish_good(t)
        rig.wait_output(t, 30.0)
        t += 0.04
    rss["start"] = node.rss_kb()
    if hammer:
        hammer.start()
    samples = []
    for i in range(args.frames):
        if not node.alive():
            print("[driver] node died at frame %d: %s" % (i, node.exit_description()))
            break
        rig.publish_good(t)
        if rig.wait_output(t, args.frame_timeout_s):
            processed += 1
        else:
            lost += 1
        t += 0.04
        if i + 1 == args.warmup:
            rss["after_warmup"] = node.rss_kb()
        if (i + 1) % 1000 == 0:
            samples.append((i + 1, node.rss_kb()))
            print("[driver] %d frames, %d processed, %d lost, RSS %d kB, %.1f fps, %d reconfigures"
                  % (i + 1, processed, lost, samples[-1][1], (i + 1) / (time.time() - t0),
                     hammer.calls if hammer else 0), flush=True)
    rss["end"] = node.rss_kb()
    if hammer:
        hammer.stop_flag.set()
        hammer.join(10)
    wall = time.time() - t0
    alive = node.alive()
    result = {
        "mode": "soak", "frames_published": processed + lost, "frames_processed": processed,
        "frames_lost": lost, "wall_s": round(wall, 1), "fps": round((processed + lost) / wall, 1),
        "rss_kb": rss, "rss_samples": samples, "node_alive": alive,
        "reconfigure_calls": hammer.calls if hammer else 0,
        "reconfigure_errors": hammer.errors if hammer else 0,
        "diagnostics": rig.diag, "size": "%dx%d" % (W, H),
    }
    node.stop()
    ok = alive and processed >= args.frames * 0.99
    # RSS moves by several MB from frame to frame (malloc arenas of the worker threads, buffers
    # resized by reconfigure), so "flat" compares the end with the highest level reached in the
    # first quarter of the run after warm-up, not with one sample.
    early = [kb for n, kb in samples if n <= max(args.frames // 4, 1000)]
    reference = max(early + [rss.get("after_warmup", -1)])
    if reference > 0:
        growth = rss["end"] - reference
        result["rss_reference_kb"] = reference
        result["rss_growth_kb"] = growth
        ok = ok and growth <= args.max_rss_growth_kb
    result["pass"] = ok
    write_result(args, result)
    print("[driver] soak: %s" % json.dumps(result))
    return 0 if ok else 1


def overload(args, node, rig):
    node.start()
    if not rig.wait_connected():
        print("[driver] node did not subscribe")
        return 1
    t = 5000.0
    rig.publish_good(t)
    rig.wait_output(t, 30.0)
    rss_start = node.rss_kb()
    published = []
    rss_max = rss_start
    rss_samples = []
    t_start = time.time()
    period = 1.0 / args.rate
    next_t = time.time()
    while time.time() - t_start < args.seconds and node.alive():
        t += 0.04
        rig.publish_good(t)
        published.append(t)
        next_t += period
        delay = next_t - time.time()
        if delay > 0:
            time.sleep(delay)
        if len(published) % 50 == 0:
            rss_samples.append(node.rss_kb())
            rss_max = max(rss_max, rss_samples[-1])
    pub_wall = time.time() - t_start
    time.sleep(3.0)  # let the node finish what it holds
    outs = rig.outputs_since(t_start)
    d = dict(rig.diag)
    time.sleep(max(2.0, args.diag_period_s * 2))
    d = dict(rig.diag) or d
    last_published = published[-1] if published else t
    increasing = all(b > a for a, b in zip(outs, outs[1:]))
    newest_processed = bool(outs) and outs[-1] >= published[-min(len(published), 3)]
    result = {
        "mode": "overload", "published": len(published),
        "publish_rate_hz": round(len(published) / pub_wall, 1), "outputs": len(outs),
        "output_rate_hz": round(len(outs) / pub_wall, 1), "rss_start_kb": rss_start,
        "rss_max_kb": rss_max, "rss_end_kb": node.rss_kb(), "node_alive": node.alive(),
        "outputs_increasing": increasing, "last_output_is_newest": newest_processed,
        "last_published": last_published, "last_output": outs[-1] if outs else None,
        "diagnostics": {k: d.get(k) for k in ("pairs received", "pairs processed", "pairs dropped",
                                              "pairs rejected", "left images", "right images")},
    }
    node.stop()
    # Bounded: memory levels off (the second half of the run never goes above the first half by
    # more than max_rss_growth_kb) instead of growing with the backlog.
    half = len(rss_samples) // 2
    first, second = rss_samples[:half] or [rss_start], rss_samples[half:] or [rss_start]
    result["rss_first_half_max_kb"], result["rss_second_half_max_kb"] = max(first), max(second)
    bounded = max(second) - max(first) <= args.max_rss_growth_kb
    result["memory_bounded"] = bounded
    result["rss_samples_kb"] = rss_samples[::max(1, len(rss_samples) // 40)]
    ok = result["node_alive"] and increasing and newest_processed and bounded
    try:
        rec, pro = int(d["pairs received"]), int(d["pairs processed"])
        drop, rej = int(d["pairs dropped"]), int(d["pairs rejected"])
        result["accounted"] = rec == pro + drop + rej
        ok = ok and drop > 0 and abs(rec - (pro + drop + rej)) <= 1
    except (KeyError, ValueError, TypeError):
        print("[driver] no diagnostics with pair counters received")
        ok = False
    result["pass"] = ok
    write_result(args, result)
    print("[driver] overload: %s" % json.dumps(result))
    return 0 if ok else 1


# ------------------------------------------------------------------------------------------------
# inventory
# ------------------------------------------------------------------------------------------------
def inventory_cases(target):
    """(id, description, function(rig, t) -> stamp of the next good pair)."""
    nan = float("nan")

    def pair_with(rig, t, w=W, h=H, lw=None, lh=None, encoding="bgr8", step=None, data=None,
                  linfo=None, rinfo=None, left=True, right=True, rframe="stereo_optical"):
        stamp = rospy.Time.from_sec(t)
        lw = w if lw is None else lw  # one size given: both images have it
        lh = h if lh is None else lh
        ld = rig.pairs.images(lw, lh)[0] if lw > 0 and lh > 0 else b""
        rd = rig.pairs.images(w, h)[1] if w > 0 and h > 0 else b""
        li = make_image(stamp, "stereo_optical", lw, lh, encoding, data if data is not None else ld,
                        step)
        ri = make_image(stamp, rframe, w, h, encoding, data if data is not None else rd, step)
        lc = linfo if linfo is not None else make_info(stamp, "stereo_optical", lw, lh)
        rc = rinfo if rinfo is not None else make_info(stamp, rframe, w, h, tx=-F_PX * BASELINE_M)
        lc.header.stamp = stamp
        rc.header.stamp = stamp
        rig.publish(li if left else None, ri if right else None, lc, rc)

    def right_only(rig, t):
        for i in range(3):
            pair_with(rig, t + 0.04 * i, left=False)
            time.sleep(0.1)
        return t + 1.0

    def simple(**kw):
        def run(rig, t):
            pair_with(rig, t, **kw)
            return t + 1.0
        return run

    def info_case(k=None, tx=-F_PX * BASELINE_M, w=W, h=H, rframe="stereo_optical"):
        def run(rig, t):
            stamp = rospy.Time.from_sec(t)
            lc = make_info(stamp, "stereo_optical", w, h, k_override=k)
            rc = make_info(stamp, rframe, w, h, tx=tx, k_override=k)
            # camera_info first, then the pair with it again: a camera whose calibration is bad
            # from now on (endo_stereo takes the latest camera_info of each side, not the one
            # with the image's stamp; see RELIABILITY.md).
            rig.publish(None, None, lc, rc)
            time.sleep(0.3)
            pair_with(rig, t, linfo=lc, rinfo=rc, rframe=rframe)
            return t + 1.0
        return run

    def stamps_case(offsets, next_offset):
        def run(rig, t):
            for o in offsets:
                rig.publish_good(t + o)
                time.sleep(0.3)
            return t + next_offset
        return run

    k_nan = [nan, 0, W / 2.0, 0, F_PX, H / 2.0, 0, 0, 1]
    k_zero = [0.0] * 9
    cases = [
        ("empty", "empty images (0x0, no data)", simple(w=0, h=0, lw=0, lh=0, data=b"")),
        ("one_pixel", "1x1 images (camera_info 1x1)", simple(w=1, h=1)),
        ("odd_size", "odd size 321x241", simple(w=321, h=241)),
        ("size_mismatch", "left 320x240, right 318x240", simple(lw=W, lh=H, w=W - 2, h=H)),
        ("enc_32fc1", "unsupported encoding 32FC1", simple(encoding="32FC1",
                                                           data=b"\0" * (W * H * 4))),
        ("enc_bayer", "encoding bayer_rggb8 (not supported by endo_stereo)",
         simple(encoding="bayer_rggb8", data=b"\x80" * (W * H))),
        ("enc_unknown", "unknown encoding 'no_such_encoding'",
         simple(encoding="no_such_encoding", data=b"\0" * (W * H * 3))),
        ("step_short", "step shorter than a row (step = 3W - 3)",
         simple(step=W * 3 - 3)),
        ("truncated", "data truncated to half the image",
         simple(data=b"\x80" * (W * H * 3 // 2))),
        ("info_nan", "NaN in camera_info K", info_case(k=k_nan)),
        ("info_zero", "all-zero camera_info K", info_case(k=k_zero)),
        ("baseline_zero", "zero baseline (right P Tx = 0)", info_case(tx=0.0)),
        ("baseline_negative", "negative baseline (right P Tx > 0)",
         info_case(tx=F_PX * BASELINE_M)),
        ("calib_size", "camera_info 640x480 for 320x240 images", info_case(w=640, h=480)),
        ("out_of_order", "stamps out of order (t, then t - 0.1 s)",
         stamps_case([0.0, -0.1], 1.0)),
        ("duplicate", "duplicated stamps (the same pair twice)", stamps_case([0.0, 0.0], 1.0)),
        ("jump_back", "time jumping back 100 s (a looping bag), stream continues from there",
         stamps_case([0.0, -100.0], -100.0 + 0.04)),
        ("range_larger", "48x32 pair with the default search range (64 px > width)",
         simple(w=48, h=32)),
        ("frame_ids", "left and right camera_info with different frame_ids",
         info_case(rframe="other_camera_frame")),
        ("right_only", "right image without a left one (3 right images)", right_only),
    ]
    return cases


def reconfigure_cases(target):
    if target == "endo_stereo":
        return [
            ("reconf_even_window", "dynamic_reconfigure: window_min_px = 4 (must be odd)",
             {"matcher_window_min_px": 4}),
            ("reconf_min_gt_max", "dynamic_reconfigure: min_disparity 40 > max_disparity 20",
             {"matcher_min_disparity": 40, "matcher_max_disparity": 20}),
            ("reconf_range_huge", "dynamic_reconfigure: search range 0..1024 (> image width)",
             {"matcher_min_disparity": 0, "matcher_max_disparity": 1024}),
        ]
    return [
        ("reconf_even_window", "dynamic_reconfigure: correlation_window_size = 4 (must be odd)",
         {"correlation_window_size": 4}),
        ("reconf_min_gt_max", "dynamic_reconfigure: disparity_range = 17 (not a multiple of 16)",
         {"disparity_range": 17}),
        ("reconf_range_huge", "dynamic_reconfigure: min_disparity 128 + range 256 (> width)",
         {"min_disparity": 128, "disparity_range": 256}),
    ]


def run_case(rig, node, t, cid, desc, fn, args):
    before = time.time()
    if not node.alive():
        node.start()
        rig.wait_connected()
        time.sleep(1.0)
        rig.publish_good(t)
        rig.wait_output(t, args.frame_timeout_s)
        t += 1.0
        before = time.time()
    n_before = len(rig.outputs_since(0))
    with rig.lock:
        rejected_before = int(rig.diag.get("pairs rejected", 0) or 0)
        rig.diag = {}
    next_t = fn(rig, t)
    time.sleep(args.settle_s)
    bad_outputs = len(rig.outputs_since(0)) - n_before
    alive = node.alive()
    death = None if alive else node.exit_description()
    death_msg = [] if alive else node.last_log_lines(
        2, pattern=["Assertion", "terminate called", "what()", "Segmentation", "Aborted"])
    recovered = False
    if alive:
        rig.publish_good(next_t)
        recovered = rig.wait_output(next_t, args.frame_timeout_s)
        if not recovered:  # one more try: some nodes drop the first pair after a reset
            rig.publish_good(next_t + 0.04)
            recovered = rig.wait_output(next_t + 0.04, args.frame_timeout_s)
    logs = rig.logs_since(before)
    # Throttled log messages may be suppressed within a case; the diagnostics' "last error"
    # (endo_stereo) says what was refused.
    last_error = None
    if alive and int(rig.diag.get("pairs rejected", 0) or 0) > rejected_before:
        last_error = rig.diag.get("last error")
    row = {"id": cid, "input": desc, "alive": alive, "death": death, "last_error": last_error,
           "death_message": death_msg, "outputs_for_bad_input": bad_outputs,
           "next_good_pair_processed": recovered,
           "log": logs[:2]}
    print("[driver] %-18s alive=%s recovered=%s outputs=%d log=%s | %s %s" % (
        cid, alive, recovered, bad_outputs, (logs[:1] or [""])[0][:110], (last_error or "")[:110],
        ("DIED: %s %s" % (death, death_msg)) if not alive else ""), flush=True)
    return row, max(next_t, t) + 1.0


def inventory(args, node, rig):
    rows = []
    node.start()
    rig.wait_connected()
    time.sleep(1.0)
    t = 2000.0
    rig.publish_good(t)
    if not rig.wait_output(t, 30.0):
        print("[driver] the node does not process a good pair; aborting")
        node.stop()
        return 1
    t += 1.0
    for cid, desc, fn in inventory_cases(args.target):
        row, t = run_case(rig, node, t, cid, desc, fn, args)
        rows.append(row)
        if cid == "jump_back":
            t += 200.0  # back past the stamps used before the jump
    # dynamic_reconfigure with values the node must refuse or clamp.
    import dynamic_reconfigure.client
    for cid, desc, cfg in reconfigure_cases(args.target):
        def fn(rig_, t_, cfg=cfg):
            try:
                client = dynamic_reconfigure.client.Client(node.name, timeout=10)
                got = client.update_configuration(cfg)
                fn.applied = {k: got.get(k) for k in cfg}
                client.close()
            except Exception as ex:  # noqa: BLE001
                fn.applied = "error: %s" % ex
            return t_ + 1.0
        fn.applied = None
        row, t = run_case(rig, node, t, cid, desc, fn, args)
        row["config_after"] = fn.applied
        rows.append(row)
        # Back to the defaults for the next case: a fresh node.
        node.stop()
        node.start()
        rig.wait_connected()
        time.sleep(1.0)
    node.stop()
    # Missing tf (endo_stereo only: stereo_image_proc has no target_frame option).
    if args.target == "endo_stereo":
        node.start({"target_frame": "no_such_frame", "tf_timeout_s": 0.01})
        rig.wait_connected()
        time.sleep(1.0)
        p0 = rig.points

        def fn_tf(rig_, t_):
            rig_.publish_good(t_)
            rig_.wait_output(t_, args.frame_timeout_s)
            return t_ + 1.0
        row, t = run_case(rig, node, t, "missing_tf", "target_frame without a transform",
                          fn_tf, args)
        row["points_published"] = rig.points - p0
        rows.append(row)
        node.stop()
    # /use_sim_time with a /clock publisher (a rosbag played with --clock).
    rospy.set_param("/use_sim_time", True)
    clock_pub = rospy.Publisher("/clock", Clock, queue_size=10)
    stop = threading.Event()

    def clock_loop():
        c = 3000.0
        while not stop.is_set():
            clock_pub.publish(Clock(clock=rospy.Time.from_sec(c)))
            c += 0.01
            time.sleep(0.01)
    th = threading.Thread(target=clock_loop, daemon=True)
    th.start()
    node.start()
    rig.wait_connected()
    time.sleep(1.5)

    def fn_sim(rig_, t_):
        rig_.publish_good(3001.0)
        return 3002.0
    row, t = run_case(rig, node, 3001.0, "use_sim_time", "/use_sim_time true, /clock published",
                      fn_sim, args)
    rows.append(row)
    stop.set()
    node.stop()
    rospy.set_param("/use_sim_time", False)
    write_result(args, {"mode": "inventory", "target": args.target, "rows": rows})
    return 0


def describe(row):
    """One table cell: what the node did with the bad input and whether it recovered."""
    if not row["alive"]:
        msg = " ".join(row.get("death_message") or [])
        for key in ("what():", "Assertion"):
            if key in msg:
                msg = msg[msg.index(key):]
                break
        return "**dies** (%s): `%s`" % (row["death"], msg[:150].replace("|", "/"))
    said = row.get("last_error") or (row.get("log") or [""])[0]
    said = said.replace("|", "/").replace("\n", " ")
    parts = []
    if row["outputs_for_bad_input"]:
        parts.append("publishes %d output(s)" % row["outputs_for_bad_input"])
    else:
        parts.append("no output")
    if said:
        parts.append("says `%s`" % said[:160])
    else:
        parts.append("nothing logged")
    if "config_after" in row:
        parts.append("config after: `%s`" % json.dumps(row["config_after"]))
    if "points_published" in row:
        parts.append("%d clouds" % row["points_published"])
    parts.append("next pair processed" if row["next_good_pair_processed"]
                 else "**next pair NOT processed**")
    return "; ".join(parts)


def inventory_table(paths):
    tables = [json.load(open(p)) for p in paths]
    by_id = [{r["id"]: r for r in t["rows"]} for t in tables]
    ids = []
    for t in tables:
        for r in t["rows"]:
            if r["id"] not in ids:
                ids.append(r["id"])
    out = ["| input | " + " | ".join(t["target"] for t in tables) + " |",
           "|---" * (len(tables) + 1) + "|"]
    for i in ids:
        desc = next(b[i]["input"] for b in by_id if i in b)
        cells = []
        for b in by_id:
            if i not in b:
                cells.append("n/a")
                continue
            cell = describe(b[i])
            # The same fault in the other node's own parameter names (reconfigure cases).
            if b[i]["input"] != desc:
                cell = "(sent: %s) %s" % (b[i]["input"].replace("|", "/"), cell)
            cells.append(cell)
        out.append("| %s | %s |" % (desc, " | ".join(cells)))
    return "\n".join(out)


def write_result(args, result):
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mode", choices=["soak", "overload", "inventory", "table"])
    ap.add_argument("inputs", nargs="*", help="table: inventory JSON files (endo_stereo first)")
    ap.add_argument("--target", default="endo_stereo", choices=["endo_stereo", "stereo_image_proc"])
    ap.add_argument("--node-exe", default=None, help="endo_stereo_node executable")
    ap.add_argument("--log-dir", default="/tmp/es_reliability")
    ap.add_argument("--out", default=None, help="JSON result file")
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--warmup", type=int, default=500)
    ap.add_argument("--frame-timeout-s", type=float, default=10.0)
    ap.add_argument("--max-rss-growth-kb", type=int, default=8192)
    ap.add_argument("--no-hammer", dest="hammer", action="store_false")
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--settle-s", type=float, default=1.5)
    ap.add_argument("--diag-period-s", type=float, default=1.0)
    ap.add_argument("--param", action="append", default=[],
                    help="private parameter of the node, key=value (YAML value)")
    args = ap.parse_args()
    if args.mode == "table":
        print(inventory_table(args.inputs))
        return 0
    os.makedirs(args.log_dir, exist_ok=True)
    rospy.init_node("es_reliability_driver", anonymous=True, disable_signals=True)
    import yaml
    params = {}
    for kv in args.param:
        k, v = kv.split("=", 1)
        params[k] = yaml.safe_load(v)
    node = NodeProcess(args.target, args.log_dir, args.node_exe, params)
    rig = Rig(node.name)
    try:
        if args.mode == "soak":
            return soak(args, node, rig)
        if args.mode == "overload":
            return overload(args, node, rig)
        return inventory(args, node, rig)
    finally:
        node.stop()
        rospy.signal_shutdown("done")


if __name__ == "__main__":
    sys.exit(main())
