#!/usr/bin/python3
"""Drives and records the endo_stereo demo (scripts/demo.sh) and the ROS benchmark
(scripts/bench_ros.sh). Runs with /usr/bin/python3 (the ROS Python modules), numpy and matplotlib.

Subcommands:
  paced  --bag B --ns NS --out DIR [--hold-s S]
      Plays the bag's stereo pairs through the nodelet one at a time: pair k+1 is published once
      the disparity of pair k came back (or a timeout), so every frame is processed and the
      pictures (disparity, coverage, cloud) show what the method does over consecutive frames.
      Writes DIR/disparity_color.png, left_rect.png, coverage.png, cloud.ply, cloud.png,
      paced.json. Then republishes the last outputs, latched, under /demo_view/ for S seconds
      (for an rviz screenshot) and writes DIR/.view_ready.
  invivo --frames-dir D --ns NS --out DIR [--count N] [--focal-px F] [--baseline-m B] [--hold-s S]
      Plays the first N rectified pairs of D (left/0001.png, right/0001.png, ...) through a
      pass_through nodelet one at a time, with a camera_info of an assumed focal length and
      baseline (the frames come without calibration), and keeps the RGB-D outputs of the last:
      DIR/depth.png (the depth picture), DIR/invivo_rgbd.json (depth figures, camera_info) and
      DIR/figures.md (the same as a table). Then
      republishes them, latched, under /demo_invivo_view/ (depth/image_rect, depth/camera_info,
      rgb/image_rect_color, rgb/camera_info, disparity_color, left/image_rect_color) for S
      seconds (for an rviz screenshot of the DepthCloud) and writes DIR/.view_ready.
  listen --ns NS [--ns NS2 ...] --frames N --out FILE.json --done-file F [--timeout-s T]
      Records, per namespace, when each input left image and each disparity arrived (wall
      clock), while something else (rosbag play) publishes. Stops when F exists and the outputs
      have settled. Writes per-namespace figures: pairs in, outputs, output rate, drops, median
      and p90 latency (left image received -> disparity received, same stamp), density.
"""
import argparse
import json
import math
import os
import struct
import sys
import threading
import time

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import rosbag  # noqa: E402
import rospy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402


# --------------------------------------------------------------------------------------------
# Message helpers (no cv_bridge / cv2 needed)
# --------------------------------------------------------------------------------------------

def image_to_array(msg):
    """sensor_msgs/Image -> numpy array (bgr8, mono8, mono16, 32FC1)."""
    kinds = {"bgr8": (np.uint8, 3), "rgb8": (np.uint8, 3), "mono8": (np.uint8, 1),
             "mono16": (np.uint16, 1), "16UC1": (np.uint16, 1), "32FC1": (np.float32, 1)}
    dtype, ch = kinds[msg.encoding]
    row = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)
    row = row[:, : msg.width * ch * np.dtype(dtype).itemsize]
    a = row.copy().view(dtype).reshape(msg.height, msg.width, ch) if ch > 1 else \
        row.copy().view(dtype).reshape(msg.height, msg.width)
    if msg.encoding == "rgb8":
        a = a[:, :, ::-1]
    return a


def disparity_to_array(msg):
    d = image_to_array(msg.image).astype(np.float32)
    d[d < msg.min_disparity] = np.nan
    return d


def cloud_to_arrays(msg):
    """Organized x y z rgb cloud -> (H, W, 3) float xyz, (H, W, 3) uint8 rgb."""
    offs = {f.name: f.offset for f in msg.fields}
    raw = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.row_step)
    raw = raw[:, : msg.width * msg.point_step].reshape(msg.height, msg.width, msg.point_step)
    xyz = np.stack([raw[:, :, offs[k]: offs[k] + 4].copy().view(np.float32)[:, :, 0]
                    for k in ("x", "y", "z")], axis=-1)
    rgb = np.zeros(xyz.shape, dtype=np.uint8)
    if "rgb" in offs:
        packed = raw[:, :, offs["rgb"]: offs["rgb"] + 4].copy().view(np.uint32)[:, :, 0]
        rgb[:, :, 0] = (packed >> 16) & 0xFF
        rgb[:, :, 1] = (packed >> 8) & 0xFF
        rgb[:, :, 2] = packed & 0xFF
    return xyz, rgb


def write_ply(path, xyz, rgb):
    ok = np.isfinite(xyz).all(axis=-1)
    pts, col = xyz[ok].astype("<f4"), rgb[ok]
    with open(path, "wb") as f:
        f.write(("ply\nformat binary_little_endian 1.0\nelement vertex %d\n"
                 "property float x\nproperty float y\nproperty float z\n"
                 "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
                 % len(pts)).encode())
        rec = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                         ("r", "u1"), ("g", "u1"), ("b", "u1")])
        rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
        rec["r"], rec["g"], rec["b"] = col[:, 0], col[:, 1], col[:, 2]
        f.write(rec.tobytes())
    return int(ok.sum())


def render_cloud(path, xyz, rgb, width=960, height=720):
    """A picture of the cloud from an oblique viewpoint (software z-buffer, no GL needed): the
    camera orbits 35 degrees around the cloud's centre so relief and depth are visible."""
    ok = np.isfinite(xyz).all(axis=-1)
    p, c = xyz[ok].astype(np.float64), rgb[ok]
    if len(p) == 0:
        return False
    centre = np.median(p, axis=0)
    a = math.radians(35.0)  # orbit around the x axis (look from above the tissue)
    b = math.radians(-20.0)  # and a little from the side
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    q = (p - centre) @ (ry @ rx).T
    dist = 1.3 * np.ptp(p[:, 0])
    q[:, 2] += dist
    f = 0.9 * width
    u = (f * q[:, 0] / q[:, 2] + width / 2).astype(np.int64)
    v = (f * q[:, 1] / q[:, 2] + height / 2).astype(np.int64)
    inside = (u >= 0) & (u < width - 1) & (v >= 0) & (v < height - 1) & (q[:, 2] > 0)
    u, v, z, c = u[inside], v[inside], q[inside, 2], c[inside]
    order = np.argsort(-z)  # far first, near points overwrite
    img = np.full((height, width, 3), 24, dtype=np.uint8)
    for du in (0, 1):
        for dv in (0, 1):
            img[v[order] + dv, u[order] + du] = c[order]
    plt.imsave(path, img)
    return True


def colourise(values, vmin, vmax, cmap="turbo", invalid=None):
    t = np.clip((values.astype(np.float64) - vmin) / max(1e-9, vmax - vmin), 0, 1)
    # Start the map above its darkest colours so that 0 stays apart from black (= invalid).
    rgb = (plt.get_cmap(cmap)(0.1 + 0.9 * t)[:, :, :3] * 255).astype(np.uint8)
    if invalid is not None:
        rgb[invalid] = 0
    return rgb


def central_region(h, w):
    ch, cw = int(round(h / math.sqrt(2))), int(round(w / math.sqrt(2)))
    y0, x0 = (h - ch) // 2, (w - cw) // 2
    return slice(y0, y0 + ch), slice(x0, x0 + cw)


def diag_values(msg, nodelet):
    want = nodelet.lstrip("/") + ": "
    out = {}
    for s in msg.status:
        if s.name.startswith(want):
            for kv in s.values:
                out[kv.key] = kv.value
    return out


# --------------------------------------------------------------------------------------------
# paced
# --------------------------------------------------------------------------------------------

def read_pairs(bag_path, ns):
    """Stereo frames of the bag: list of dicts (left, right, left_info, right_info) by stamp."""
    topics = {ns + "/left/image_raw": "left", ns + "/right/image_raw": "right",
              ns + "/left/camera_info": "left_info", ns + "/right/camera_info": "right_info"}
    frames = {}
    with rosbag.Bag(bag_path) as bag:
        for topic, msg, _ in bag.read_messages(topics=list(topics)):
            frames.setdefault(msg.header.stamp, {})[topics[topic]] = msg
    return [frames[k] for k in sorted(frames) if "left" in frames[k] and "right" in frames[k]]


def paced(args):
    rospy.init_node("endo_stereo_demo_player", anonymous=True, disable_signals=True)
    ns = args.ns.rstrip("/")
    frames = read_pairs(args.bag, ns)
    if not frames:
        sys.exit("no stereo pairs under %s in %s" % (ns, args.bag))
    lock = threading.Condition()
    last = {}
    stamps_out = {}
    densities = []

    def keep(name):
        def cb(msg):
            with lock:
                last[name] = msg
                if name == "disparity":
                    stamps_out[msg.header.stamp] = time.time()
                    d = disparity_to_array(msg)
                    densities.append(float(np.isfinite(d).mean()))
                lock.notify_all()
        return cb

    subs = [rospy.Subscriber(ns + "/disparity", DisparityImage, keep("disparity"), queue_size=5),
            rospy.Subscriber(ns + "/disparity_color", Image, keep("disparity_color"), queue_size=2),
            rospy.Subscriber(ns + "/coverage", Image, keep("coverage"), queue_size=2),
            rospy.Subscriber(ns + "/points2", PointCloud2, keep("points2"), queue_size=2,
                             buff_size=2 ** 26),
            rospy.Subscriber(ns + "/left/image_rect_color", Image, keep("left_rect"), queue_size=2,
                             buff_size=2 ** 24)]
    pub_l = rospy.Publisher(ns + "/left/image_raw", Image, queue_size=2)
    pub_r = rospy.Publisher(ns + "/right/image_raw", Image, queue_size=2)
    pub_li = rospy.Publisher(ns + "/left/camera_info", CameraInfo, queue_size=1, latch=True)
    pub_ri = rospy.Publisher(ns + "/right/camera_info", CameraInfo, queue_size=1, latch=True)

    # Lazy subscription: the nodelet subscribes once our output subscribers are connected.
    deadline = time.time() + 60
    while time.time() < deadline and (pub_l.get_num_connections() == 0 or
                                      pub_r.get_num_connections() == 0 or
                                      pub_li.get_num_connections() == 0):
        time.sleep(0.05)
    if "left_info" in frames[0]:
        pub_li.publish(frames[0]["left_info"])
        pub_ri.publish(frames[0]["right_info"])
    time.sleep(0.3)  # the latched camera_info reaches the nodelet before the first pair

    latencies, processed = [], 0
    t_start = time.time()
    for i, fr in enumerate(frames):
        stamp = fr["left"].header.stamp
        t0 = time.time()
        pub_l.publish(fr["left"])
        pub_r.publish(fr["right"])
        with lock:
            ok = lock.wait_for(lambda: stamp in stamps_out, timeout=args.frame_timeout_s)
        if ok:
            processed += 1
            latencies.append(stamps_out[stamp] - t0)
        sys.stdout.write("\r[demo] frame %d/%d %s" % (i + 1, len(frames),
                                                       "ok" if ok else "no output (timeout)"))
        sys.stdout.flush()
    wall = time.time() - t_start
    print()
    time.sleep(0.5)  # the last frame's other outputs (cloud, coverage) follow the disparity

    os.makedirs(args.out, exist_ok=True)
    figures = {"frames": len(frames), "processed": processed, "wall_s": wall,
               "width": frames[0]["left"].width, "height": frames[0]["left"].height}
    if latencies:
        lat = np.array(latencies) * 1e3
        figures.update({"latency_median_ms": float(np.median(lat)),
                        "latency_p90_ms": float(np.percentile(lat, 90)),
                        "processing_fps": float(1e3 / np.median(lat))})
    if densities:
        figures.update({"density_mean": float(np.mean(densities)),
                        "density_last": float(densities[-1])})
    with lock:
        snap = dict(last)
    if "disparity_color" in snap:
        plt.imsave(os.path.join(args.out, "disparity_color.png"),
                   image_to_array(snap["disparity_color"])[:, :, ::-1])
    if "left_rect" in snap:
        plt.imsave(os.path.join(args.out, "left_rect.png"),
                   image_to_array(snap["left_rect"])[:, :, ::-1])
    if "coverage" in snap:
        run = image_to_array(snap["coverage"]).astype(np.int64)
        n = args.within_frames
        never = run >= processed  # never updated in the frames processed
        plt.imsave(os.path.join(args.out, "coverage.png"),
                   colourise(np.minimum(run, 2 * n), 0, 2 * n, invalid=never))
        cy, cx = central_region(*run.shape)
        figures.update({
            "coverage_within_frames": n,
            "coverage_central_share": float((run[cy, cx] < n).mean()),
            "coverage_overall_share": float((run < n).mean()),
            "coverage_central_never": float(never[cy, cx].mean())})
    if "points2" in snap:
        xyz, rgb = cloud_to_arrays(snap["points2"])
        figures["cloud_points"] = write_ply(os.path.join(args.out, "cloud.ply"), xyz, rgb)
        z = xyz[:, :, 2][np.isfinite(xyz[:, :, 2])]
        if len(z):
            figures.update({"cloud_depth_median_m": float(np.median(z)),
                            "cloud_depth_p5_m": float(np.percentile(z, 5)),
                            "cloud_depth_p95_m": float(np.percentile(z, 95))})
        render_cloud(os.path.join(args.out, "cloud.png"), xyz, rgb)
    with open(os.path.join(args.out, "paced.json"), "w") as f:
        json.dump(figures, f, indent=2)

    # Hold the last outputs, latched, for an rviz screenshot.
    if args.hold_s > 0 and "points2" in snap:
        view = [rospy.Publisher("/demo_view/points2", PointCloud2, queue_size=1, latch=True),
                rospy.Publisher("/demo_view/disparity_color", Image, queue_size=1, latch=True),
                rospy.Publisher("/demo_view/left/image_rect_color", Image, queue_size=1, latch=True)]
        for s in subs:
            s.unregister()
        for pub, key in zip(view, ("points2", "disparity_color", "left_rect")):
            if key in snap:
                pub.publish(snap[key])
        open(os.path.join(args.out, ".view_ready"), "w").close()
        end = time.time() + args.hold_s
        while time.time() < end and not os.path.exists(os.path.join(args.out, ".view_done")):
            # rviz's Image displays show a message only when it arrives: publish again now and then.
            for pub, key in zip(view, ("points2", "disparity_color", "left_rect")):
                if key in snap and pub.get_num_connections() > 0:
                    pub.publish(snap[key])
            time.sleep(1.0)
    rospy.signal_shutdown("done")


# --------------------------------------------------------------------------------------------
# invivo
# --------------------------------------------------------------------------------------------

def array_to_image(a, encoding, stamp, frame_id):
    msg = Image()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.height, msg.width = a.shape[0], a.shape[1]
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = a.shape[1] * (a.shape[2] if a.ndim == 3 else 1) * a.dtype.itemsize
    msg.data = np.ascontiguousarray(a).tobytes()
    return msg


def read_png_bgr(path):
    a = plt.imread(path)  # PNG: float in [0, 1], RGB or RGBA
    a = (np.clip(a[:, :, :3], 0, 1) * 255 + 0.5).astype(np.uint8)
    return np.ascontiguousarray(a[:, :, ::-1])


def invivo(args):
    rospy.init_node("endo_stereo_demo_invivo", anonymous=True, disable_signals=True)
    ns = args.ns.rstrip("/")
    pairs = []
    for i in range(1, args.count + 1):
        lp = os.path.join(args.frames_dir, "left", "%04d.png" % i)
        rp = os.path.join(args.frames_dir, "right", "%04d.png" % i)
        if not (os.path.exists(lp) and os.path.exists(rp)):
            break
        pairs.append((read_png_bgr(lp), read_png_bgr(rp)))
    if not pairs:
        sys.exit("no pairs in %s" % args.frames_dir)
    h, w = pairs[0][0].shape[:2]
    frame = "invivo_left_optical"
    # The frames are rectified but come without calibration: an assumed pinhole camera (the
    # principal point at the centre) and baseline give depth of the right shape, not of the
    # right scale.
    infos = []
    for side, tx in (("left", 0.0), ("right", -args.focal_px * args.baseline_m)):
        ci = CameraInfo()
        ci.header.frame_id = "invivo_%s_optical" % side
        ci.width, ci.height = w, h
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        ci.distortion_model = "plumb_bob"
        ci.D = [0.0] * 5
        ci.K = [args.focal_px, 0, cx, 0, args.focal_px, cy, 0, 0, 1]
        ci.R = [1, 0, 0, 0, 1, 0, 0, 0, 1]
        ci.P = [args.focal_px, 0, cx, tx, 0, args.focal_px, cy, 0, 0, 0, 1, 0]
        infos.append(ci)

    lock = threading.Condition()
    last = {}

    def keep(name):
        def cb(msg):
            with lock:
                last.setdefault(name, {})[msg.header.stamp] = msg
                lock.notify_all()
        return cb

    names = {"depth": ("depth/image_rect", Image), "depth_info": ("depth/camera_info", CameraInfo),
             "rgb": ("rgb/image_rect_color", Image), "rgb_info": ("rgb/camera_info", CameraInfo),
             "disparity_color": ("disparity_color", Image)}
    subs = [rospy.Subscriber(ns + "/" + topic, kind, keep(name), queue_size=5, buff_size=2 ** 24)
            for name, (topic, kind) in names.items()]
    pub_l = rospy.Publisher(ns + "/left/image_rect", Image, queue_size=2)
    pub_r = rospy.Publisher(ns + "/right/image_rect", Image, queue_size=2)
    pub_li = rospy.Publisher(ns + "/left/camera_info", CameraInfo, queue_size=1, latch=True)
    pub_ri = rospy.Publisher(ns + "/right/camera_info", CameraInfo, queue_size=1, latch=True)
    deadline = time.time() + 60
    while time.time() < deadline and (pub_l.get_num_connections() == 0 or
                                      pub_r.get_num_connections() == 0 or
                                      pub_li.get_num_connections() == 0):
        time.sleep(0.05)
    pub_li.publish(infos[0])
    pub_ri.publish(infos[1])
    time.sleep(0.3)  # the latched camera_info reaches the nodelet before the first pair

    t0 = rospy.Time(1700000000, 0)
    done = None
    for i, (l, r) in enumerate(pairs):
        stamp = t0 + rospy.Duration(0.04 * i)
        pub_l.publish(array_to_image(l, "bgr8", stamp, frame))
        pub_r.publish(array_to_image(r, "bgr8", stamp, infos[1].header.frame_id))
        with lock:
            ok = lock.wait_for(lambda: all(stamp in last.get(n, {}) for n in names),
                               timeout=args.frame_timeout_s)
        if ok:
            done = stamp
        sys.stdout.write("\r[demo] in-vivo frame %d/%d %s" % (
            i + 1, len(pairs), "ok" if ok else "no RGB-D output (timeout)"))
        sys.stdout.flush()
    print()
    for s_ in subs:
        s_.unregister()
    if done is None:
        sys.exit("no complete RGB-D output from %s" % ns)
    with lock:
        snap = {n: last[n][done] for n in names}
    depth = image_to_array(snap["depth"])
    ok = np.isfinite(depth)
    figures = {"frames": len(pairs), "width": w, "height": h,
               "assumed_focal_px": args.focal_px, "assumed_baseline_m": args.baseline_m,
               "depth_valid_share": float(ok.mean()),
               "depth_median_m": float(np.median(depth[ok])) if ok.any() else None,
               "depth_p5_m": float(np.percentile(depth[ok], 5)) if ok.any() else None,
               "depth_p95_m": float(np.percentile(depth[ok], 95)) if ok.any() else None,
               "depth_camera_info_K": list(snap["depth_info"].K),
               "depth_frame": snap["depth"].header.frame_id}
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "invivo_rgbd.json"), "w") as f:
        json.dump(figures, f, indent=2)
    lines = ["## RGB-D output on the real in-vivo frames (rviz DepthCloud: rviz_invivo_depthcloud.png)",
             "| figure | value |", "|---|---|",
             "| frames played (pass_through, one at a time) | %d of %dx%d |" % (len(pairs), w, h),
             "| assumed camera (the frames come without calibration) | f %.0f px, baseline %.1f mm |"
             % (args.focal_px, 1e3 * args.baseline_m)]
    if ok.any():
        lines.append("| depth/image_rect of the last frame: valid share, median (5-95%%) | "
                     "%.3f, %.1f mm (%.1f-%.1f) |"
                     % (figures["depth_valid_share"], 1e3 * figures["depth_median_m"],
                        1e3 * figures["depth_p5_m"], 1e3 * figures["depth_p95_m"]))
    with open(os.path.join(args.out, "figures.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    if ok.any():
        lo, hi = figures["depth_p5_m"], figures["depth_p95_m"]
        plt.imsave(os.path.join(args.out, "depth.png"),
                   colourise(np.where(ok, depth, lo), lo, hi, invalid=~ok))

    if args.hold_s > 0:
        view = {"depth": ("depth/image_rect", Image), "depth_info": ("depth/camera_info", CameraInfo),
                "rgb": ("rgb/image_rect_color", Image), "rgb_info": ("rgb/camera_info", CameraInfo),
                "disparity_color": ("disparity_color", Image),
                "left_rect": ("left/image_rect_color", Image)}
        pubs = {n: rospy.Publisher("/demo_invivo_view/" + topic, kind, queue_size=1, latch=True)
                for n, (topic, kind) in view.items()}
        snap["left_rect"] = snap["rgb"]
        for n, p in pubs.items():
            p.publish(snap[n])
        open(os.path.join(args.out, ".view_ready"), "w").close()
        end = time.time() + args.hold_s
        while time.time() < end and not os.path.exists(os.path.join(args.out, ".view_done")):
            # rviz shows a message when it arrives: publish again now and then, camera_info first
            # (the DepthCloud needs one before a depth image).
            for n in ("depth_info", "rgb_info", "depth", "rgb", "disparity_color", "left_rect"):
                if pubs[n].get_num_connections() > 0:
                    pubs[n].publish(snap[n])
            time.sleep(1.0)
    rospy.signal_shutdown("done")


# --------------------------------------------------------------------------------------------
# listen
# --------------------------------------------------------------------------------------------

def listen(args):
    rospy.init_node("endo_stereo_bench_listener", anonymous=True, disable_signals=True)
    lock = threading.Lock()
    rec = {}
    for ns in args.ns:
        ns = ns.rstrip("/")
        r = rec[ns] = {"in": {}, "out": {}, "density": [], "diag": {}}

        def on_left(msg, r=r):
            with lock:
                r["in"].setdefault(msg.header.stamp, time.time())

        def on_disp(msg, r=r):
            t = time.time()
            d = disparity_to_array(msg)
            with lock:
                r["out"][msg.header.stamp] = t
                r["density"].append(float(np.isfinite(d).mean()))

        # Header-only interest in the left images, but rospy must deserialize them anyway; the
        # cost is the same for every peer listened to.
        rospy.Subscriber(ns + "/left/image_raw", Image, on_left, queue_size=50, buff_size=2 ** 26)
        rospy.Subscriber(ns + "/disparity", DisparityImage, on_disp, queue_size=50,
                         buff_size=2 ** 26)

    def on_diag(msg):
        with lock:
            for ns, r in rec.items():
                for name in args.nodelet:
                    v = diag_values(msg, name)
                    if v and name.startswith(ns + "/"):
                        r["diag"] = v

    rospy.Subscriber("/diagnostics", DiagnosticArray, on_diag, queue_size=50)
    open(args.ready_file, "w").close() if args.ready_file else None
    deadline = time.time() + args.timeout_s
    while time.time() < deadline and not os.path.exists(args.done_file):
        time.sleep(0.1)
    # Let the last outputs arrive: settled when nothing came for 2 s.
    last_count, quiet_since = -1, time.time()
    while time.time() < deadline and time.time() - quiet_since < 2.0:
        with lock:
            n = sum(len(r["out"]) for r in rec.values())
        if n != last_count:
            last_count, quiet_since = n, time.time()
        time.sleep(0.1)

    result = {}
    with lock:
        for ns, r in rec.items():
            ins = sorted(r["in"])
            outs = sorted(r["out"])
            lat = [1e3 * (r["out"][s] - r["in"][s]) for s in outs if s in r["in"]]
            span = (max(r["out"].values()) - min(r["out"].values())) if len(outs) > 1 else 0.0
            in_span = (max(r["in"].values()) - min(r["in"].values())) if len(ins) > 1 else 0.0
            res = {"frames_in_bag": args.frames, "pairs_in": len(ins), "outputs": len(outs),
                   "dropped_or_lost": len(ins) - len(outs),
                   # Where in the input the pairs without an output were (0 = the first pair):
                   # start-up against steady state.
                   "dropped_indices": [i for i, s in enumerate(ins) if s not in r["out"]],
                   "input_rate_hz": (len(ins) - 1) / in_span if in_span > 0 else None,
                   "output_rate_hz": (len(outs) - 1) / span if span > 0 else None,
                   "output_rate_over_input_span_hz": len(outs) / in_span if in_span > 0 else None,
                   "latency_median_ms": float(np.median(lat)) if lat else None,
                   "latency_p90_ms": float(np.percentile(lat, 90)) if lat else None,
                   # Per input pair (None = no output): how the start-up stall is caught up.
                   "latency_per_pair_ms": [
                       round(1e3 * (r["out"][s] - r["in"][s]), 1) if s in r["out"] else None
                       for s in ins],
                   "density_mean": float(np.mean(r["density"])) if r["density"] else None,
                   "nodelet_diagnostics": r["diag"]}
            result[ns] = res
    with open(args.out, "w") as f:
        json.dump(result, f, indent=2)
    rospy.signal_shutdown("done")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("paced")
    p.add_argument("--bag", required=True)
    p.add_argument("--ns", default="/endoscope")
    p.add_argument("--out", required=True)
    p.add_argument("--hold-s", type=float, default=0.0)
    p.add_argument("--frame-timeout-s", type=float, default=60.0)
    p.add_argument("--within-frames", type=int, default=10)
    v = sub.add_parser("invivo")
    v.add_argument("--frames-dir", required=True)
    v.add_argument("--ns", default="/invivo")
    v.add_argument("--out", required=True)
    v.add_argument("--count", type=int, default=30)
    v.add_argument("--focal-px", type=float, default=400.0)
    v.add_argument("--baseline-m", type=float, default=0.005)
    v.add_argument("--hold-s", type=float, default=0.0)
    v.add_argument("--frame-timeout-s", type=float, default=60.0)
    l = sub.add_parser("listen")
    l.add_argument("--ns", action="append", required=True)
    l.add_argument("--nodelet", action="append", default=[],
                   help="diagnostics name of a nodelet to record (e.g. /endoscope/reconstruction)")
    l.add_argument("--frames", type=int, required=True)
    l.add_argument("--out", required=True)
    l.add_argument("--done-file", required=True)
    l.add_argument("--ready-file", default="")
    l.add_argument("--timeout-s", type=float, default=300.0)
    args = ap.parse_args(rospy.myargv()[1:])
    {"paced": paced, "invivo": invivo, "listen": listen}[args.cmd](args)


if __name__ == "__main__":
    main()
