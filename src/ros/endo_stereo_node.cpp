// Standalone node for users without a nodelet manager: loads endo_stereo/reconstruction in
// process, with this node's name, remappings and private parameters.
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "endo_stereo");
  nodelet::Loader loader(false);  // no load/unload services: this process runs one nodelet
  const nodelet::M_string remappings(ros::names::getRemappings());
  const nodelet::V_string nodelet_argv;
  if (!loader.load(ros::this_node::getName(), "endo_stereo/reconstruction", remappings,
                   nodelet_argv)) {
    ROS_FATAL("could not load the nodelet endo_stereo/reconstruction (is the workspace sourced?)");
    return 1;
  }
  ros::spin();
  return 0;
}
