#!/usr/bin/python3
"""The rviz configuration of the demo's in-vivo DepthCloud picture (scripts/demo.sh, step 6):
rviz/endo_stereo.rviz with its DepthCloud display on and points2 off, the fixed frame that of the
depth image, and the view scaled to the depth measured.

Usage: demo_depthcloud_view.py BASE.rviz INVIVO_RGBD.json OUT.rviz
(INVIVO_RGBD.json: written by demo_capture.py invivo; depth_frame, depth_median_m.)
"""
import json
import sys

import yaml


def main():
    base, figures, out = sys.argv[1:4]
    cfg = yaml.safe_load(open(base))
    fig = json.load(open(figures))
    vm = cfg["Visualization Manager"]
    z = fig.get("depth_median_m") or 0.03
    for d in vm["Displays"]:
        if d.get("Class") == "rviz/DepthCloud":
            d["Enabled"] = d["Value"] = True
        elif d.get("Name") == "points2":
            d["Enabled"] = d["Value"] = False
        elif d.get("Class") == "rviz/Axes":
            # The camera's axes at the scene's scale (the base view's 1 cm would fill the view).
            d["Length"] = z / 4.0
            d["Radius"] = z / 80.0
    vm["Global Options"]["Fixed Frame"] = fig["depth_frame"]
    view = vm["Views"]["Current"]
    # The base view's orbit at the scale of this depth (the focal point at the median depth, the
    # eye about as far behind the camera), tilted a little more off the camera's axis so that
    # the relief shows.
    view["Focal Point"]["Z"] = z
    view["Distance"] = 2.0 * z
    view["Pitch"] = -1.15
    with open(out, "w") as f:
        yaml.safe_dump(cfg, f, sort_keys=False)


if __name__ == "__main__":
    main()
