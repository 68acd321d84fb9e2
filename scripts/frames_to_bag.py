#!/usr/bin/python3
"""Writes rectified stereo image files as a ROS bag, the way a stereo camera driver publishes them:
NS/left/image_raw, NS/right/image_raw (bgr8) and NS/left/camera_info, NS/right/camera_info, the
four messages of a frame with the same stamp, frames at --fps. Used by scripts/bench_ros.sh (real
frames through the nodelet and stereo_image_proc) and scripts/demo.sh.

The images must already be rectified: the camera_info says so (no distortion, R = I, P = K with
the right camera's P[3] = -f * baseline). f and the baseline only scale depth; without a
calibration give any plausible pair (the defaults: f = the image width, baseline 5 mm).
Both camera_info messages carry the left optical frame (stereo_image_proc's image_geometry
requires the two frame_ids to agree).

  frames_to_bag.py --left L%04d.png --right R%04d.png --first 1 --count 150 --out in.bag
  frames_to_bag.py --left rect_left.png --right rect_right.png --crop 960x540 --pan 100 --out b.bag
      (a single pair: --pan N frames of a crop window moving on a circle of radius 24 px, one turn
      every 75 frames, as endo_stereo_evaluate --pan does)

Runs with /usr/bin/python3 (the ROS Python modules), numpy and Pillow.
"""
import argparse
import math
import os
import sys

import numpy as np
from PIL import Image as PilImage

import rosbag
import rospy
from sensor_msgs.msg import CameraInfo, Image


def load_bgr(path):
    img = PilImage.open(path)
    a = np.asarray(img.convert("RGB"))
    return np.ascontiguousarray(a[:, :, ::-1])


def image_msg(bgr, stamp, frame_id):
    m = Image()
    m.header.stamp = stamp
    m.header.frame_id = frame_id
    m.height, m.width = bgr.shape[:2]
    m.encoding = "bgr8"
    m.is_bigendian = 0
    m.step = m.width * 3
    m.data = bgr.tobytes()
    return m


def info_msg(w, h, f, baseline, right, stamp, frame_id):
    m = CameraInfo()
    m.header.stamp = stamp
    m.header.frame_id = frame_id
    m.width, m.height = w, h
    m.distortion_model = "plumb_bob"
    m.D = [0.0] * 5
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    m.K = [f, 0, cx, 0, f, cy, 0, 0, 1]
    m.R = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    m.P = [f, 0, cx, -f * baseline if right else 0.0, 0, f, cy, 0, 0, 0, 1, 0]
    return m


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--left", required=True)
    ap.add_argument("--right", required=True)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--count", type=int, default=0, help="frames of a pattern (0: until missing)")
    ap.add_argument("--crop", default="", help="WxH centre crop")
    ap.add_argument("--pan", type=int, default=0, help="single pair: frames of a moving crop")
    ap.add_argument("--pan-radius", type=int, default=24)
    ap.add_argument("--pan-period", type=int, default=75)
    ap.add_argument("--fps", type=float, default=25.0)
    ap.add_argument("--focal", type=float, default=0.0)
    ap.add_argument("--baseline", type=float, default=0.005)
    ap.add_argument("--ns", default="/endoscope")
    ap.add_argument("--start-time", type=float, default=1600000000.0)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()

    pattern = "%" in a.left
    if pattern:
        frames = []
        i = a.first
        while (a.count == 0 or len(frames) < a.count) and os.path.exists(a.left % i):
            frames.append((a.left % i, a.right % i, (0, 0)))
            i += 1
    else:
        n = a.pan if a.pan > 0 else max(1, a.count)
        frames = []
        for k in range(n):
            off = (0, 0)
            if a.pan > 0:
                t = 2 * math.pi * k / a.pan_period
                # Python's round() rounds halves to even; C's lround (the evaluation tool) away
                # from zero: the same offsets either way for these radii (no exact halves).
                off = (int(round(a.pan_radius * math.cos(t))), int(round(a.pan_radius * math.sin(t))))
            frames.append((a.left, a.right, off))
    if not frames:
        sys.exit("frames_to_bag.py: no frame found at %s" % (a.left % a.first if pattern else a.left))
    crop = tuple(int(v) for v in a.crop.split("x")) if a.crop else None
    ns = a.ns.rstrip("/")
    frame_id = ns.strip("/").replace("/", "_") + "_left_optical"
    cache = {}
    with rosbag.Bag(a.out, "w") as bag:
        for k, (lp, rp, off) in enumerate(frames):
            if lp not in cache:
                cache.clear()
                cache[lp] = (load_bgr(lp), load_bgr(rp))
            left, right = cache[lp]
            if crop:
                w, h = crop
                x0 = (left.shape[1] - w) // 2 + off[0]
                y0 = (left.shape[0] - h) // 2 + off[1]
                if x0 < 0 or y0 < 0 or x0 + w > left.shape[1] or y0 + h > left.shape[0]:
                    sys.exit("frames_to_bag.py: the crop does not fit the image")
                left = np.ascontiguousarray(left[y0:y0 + h, x0:x0 + w])
                right = np.ascontiguousarray(right[y0:y0 + h, x0:x0 + w])
            h, w = left.shape[:2]
            f = a.focal if a.focal > 0 else float(w)
            stamp = rospy.Time.from_sec(a.start_time + k / a.fps)
            bag.write(ns + "/left/image_raw", image_msg(left, stamp, frame_id), stamp)
            bag.write(ns + "/left/camera_info", info_msg(w, h, f, a.baseline, False, stamp, frame_id), stamp)
            bag.write(ns + "/right/image_raw", image_msg(right, stamp, frame_id), stamp)
            bag.write(ns + "/right/camera_info", info_msg(w, h, f, a.baseline, True, stamp, frame_id), stamp)
    print("frames_to_bag.py: %d frames %dx%d at %g fps -> %s" % (len(frames), w, h, a.fps, a.out))


if __name__ == "__main__":
    main()
