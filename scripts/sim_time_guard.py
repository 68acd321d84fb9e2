#!/usr/bin/env python3
"""Restores /use_sim_time when the launch that set it ends (launch/playback.launch).

roslaunch sets /use_sim_time before it starts any node and never removes it, so without this a
later tool on the same master would wait for a /clock that no longer ticks. The launch passes the
value the master held before it (~previous: "true", "false", or "unset", read by a command
parameter while roslaunch loads the file, before it sets its own parameters); on shutdown
(SIGINT from roslaunch, SIGTERM) this node puts that value back, or deletes the parameter.
"""
import signal
import sys

import rosgraph
import rospy


def restore(previous):
    master = rosgraph.Master(rospy.get_name())
    try:
        if previous in ("true", "false"):
            master.setParam("/use_sim_time", previous == "true")
        elif master.hasParam("/use_sim_time"):
            master.deleteParam("/use_sim_time")
    except Exception as err:  # the master may be gone already: nothing left to restore
        sys.stderr.write("sim_time_guard: could not restore /use_sim_time: %s\n" % err)


def main():
    # Wall time for this node: it must run (and shut down) whether or not /clock ticks.
    rospy.init_node("sim_time_guard", disable_signals=True)
    previous = str(rospy.get_param("~previous", "unset")).strip().lower()
    stopping = []

    def on_signal(signum, _frame):
        if not stopping:
            stopping.append(signum)
            restore(previous)
            rospy.signal_shutdown("restored /use_sim_time")

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    rospy.loginfo("on exit /use_sim_time goes back to %s", previous)
    while not stopping:
        signal.pause()


if __name__ == "__main__":
    main()
