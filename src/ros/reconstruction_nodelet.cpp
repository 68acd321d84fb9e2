// The nodelet: parameters in, Reconstruction out, dynamic_reconfigure. See the header.
#include "endo_stereo/ros/reconstruction_nodelet.hpp"

#include <stdexcept>

#include <opencv2/core/utility.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "endo_stereo/core/params_io.hpp"
#include "endo_stereo/ros/reconfigure.hpp"
#include "endo_stereo/ros/ros_params.hpp"
#include "endo_stereo/ros/stereo_image_proc_params.hpp"
#include "endo_stereo/ros/unknown_params.hpp"

namespace endo_stereo {

ReconstructionNodelet::~ReconstructionNodelet() {
  // The server's callback uses reconstruction_: stop it first.
  reconfigure_server_.reset();
  reconstruction_.reset();
}

void ReconstructionNodelet::onInit() {
  ros::NodeHandle& nh = getNodeHandle();
  ros::NodeHandle& pnh = getPrivateNodeHandle();
#if defined(__SANITIZE_THREAD__)
  // ThreadSanitizer build (make tsan): OpenCV's parallel_for_ runs on oneTBB, which is not
  // instrumented, so every hand-over to a TBB worker would be reported as a race. OpenCV's
  // sequential mode keeps TSan's view on the nodelet's own threads (callbacks, processing,
  // reconfigure, diagnostics, background quality check).
  cv::setNumThreads(0);
  NODELET_WARN("ThreadSanitizer build: OpenCV runs sequentially (cv::setNumThreads(0))");
#endif

  RosParams ros_params;
  PipelineParams params;
  StereoImageProcReport sip;
  std::string e = loadRosParams(pnh, ros_params);
  if (e.empty()) e = ros_params.validate();
  if (e.empty()) e = loadPipelineParamsFromRos(pnh, params);
  // stereo_image_proc's names last: a user types them on purpose, over the preset's values.
  if (e.empty()) e = applyStereoImageProcParams(pnh, params, &sip);
  // Each once: onInit() runs once per load.
  for (const std::string& line : sip.ignored) NODELET_WARN("%s", line.c_str());
  for (const std::string& line : sip.mapped) NODELET_INFO("%s", line.c_str());
  // A private parameter no list above reads is a typo or another tool's name: say so once.
  for (const UnknownParam& u : unknownPrivateParams(pnh, knownPrivateParams())) {
    if (u.closest.empty()) {
      NODELET_WARN("~%s is not a parameter of this node and is ignored", u.name.c_str());
    } else {
      NODELET_WARN("~%s is not a parameter of this node and is ignored; did you mean ~%s?",
                   u.name.c_str(), u.closest.c_str());
    }
  }
  if (e.empty()) e = params.validate();
  if (!e.empty()) {
    // Without valid parameters there is nothing sensible to run; say why once and stay idle
    // (throwing out of onInit() would take the whole manager down).
    NODELET_FATAL("invalid parameters, not starting: %s", e.c_str());
    return;
  }
  try {
    reconstruction_ = std::make_unique<Reconstruction>(nh, pnh, getName(), ros_params, params);
  } catch (const std::exception& ex) {
    NODELET_FATAL("cannot start: %s", ex.what());
    return;
  }
  storePipelineParamsToRos(pnh, params);
  storeStereoImageProcParams(pnh, params);

  reconfigure_server_ =
      std::make_unique<dynamic_reconfigure::Server<EndoStereoConfig>>(reconfigure_mutex_, pnh);
  // Publish the loaded parameters as the current configuration before the callback is set, so the
  // first callback (which setCallback() makes at once) changes nothing.
  reconfigure_server_->updateConfig(configFromParams(params));
  reconfigure_server_->setCallback(
      boost::bind(&ReconstructionNodelet::reconfigureCb, this, boost::placeholders::_1,
                  boost::placeholders::_2));
  std::string preset = ros_params.preset;
  if (preset.empty()) {
    std::string file;
    pnh.getParam("config_file", file);
    preset = file.empty() ? "none named (struct defaults and ~section/field parameters)" : file;
  }
  NODELET_INFO("ready: %s; preset %s; backlog %d pairs up to %.2f s; waiting for subscribers",
               reconstruction_->describe().c_str(), preset.c_str(), ros_params.backlog_pairs,
               ros_params.backlog_max_age_s);
}

void ReconstructionNodelet::reconfigureCb(EndoStereoConfig& config, uint32_t /*level*/) {
  if (!reconstruction_) return;
  const PipelineParams current = reconstruction_->pipelineParams();
  PipelineParams next;
  std::string e = paramsFromConfig(config, current, &next);
  if (e.empty()) e = reconstruction_->setPipelineParams(next);  // validates
  if (!e.empty()) {
    NODELET_ERROR("reconfigure refused, parameters unchanged: %s", e.c_str());
    // The server reports the config back after this callback: show the values in use.
    config = configFromParams(current, config);
    return;
  }
  // setCallback() calls back at once with the loaded parameters: nothing to say then.
  if (pipelineParamsToYaml(next) != pipelineParamsToYaml(current)) {
    // The parameter server shows the values in use (only those that changed are written).
    storePipelineParamsToRos(getPrivateNodeHandle(), next, &current);
    storeStereoImageProcParams(getPrivateNodeHandle(), next);
    NODELET_INFO("reconfigured (disparity range %d..%d); the new parameters apply from the next "
                 "frame", next.matcher.min_disparity, next.matcher.max_disparity);
  }
}

}  // namespace endo_stereo

PLUGINLIB_EXPORT_CLASS(endo_stereo::ReconstructionNodelet, nodelet::Nodelet)
