// ROS parameters -> core structs. See ros_params.hpp.
//
// Pipeline parameters go through params_io's setPipelineParam() as text, so the nodelet, the
// YAML presets and the command-line tools share one list of keys, one parser and one set of
// error messages.
#include "endo_stereo/ros/ros_params.hpp"

#include <cmath>
#include <sstream>

#include <XmlRpcValue.h>

#include "endo_stereo/core/params_io.hpp"

namespace endo_stereo {
namespace {

// A scalar parameter as the text params_io parses; "" in @p error when it is one.
bool scalarToText(XmlRpc::XmlRpcValue& v, std::string* text, std::string* error) {
  std::ostringstream s;
  switch (v.getType()) {
    case XmlRpc::XmlRpcValue::TypeBoolean:
      *text = static_cast<bool>(v) ? "true" : "false";
      return true;
    case XmlRpc::XmlRpcValue::TypeInt:
      *text = std::to_string(static_cast<int>(v));
      return true;
    case XmlRpc::XmlRpcValue::TypeDouble: {
      s.precision(17);
      s << static_cast<double>(v);
      *text = s.str();
      return true;
    }
    case XmlRpc::XmlRpcValue::TypeString:
      *text = static_cast<std::string>(v);
      return true;
    default:
      *error = "expected a scalar (bool, int, double or string)";
      return false;
  }
}

std::string typeError(const ros::NodeHandle& pnh, const std::string& name, const char* what) {
  return "parameter " + pnh.resolveName(name) + ": expected " + what;
}

// Typed getters that report a wrong type instead of ignoring the value as NodeHandle::param does.
std::string readParam(const ros::NodeHandle& pnh, const std::string& name, int* out) {
  XmlRpc::XmlRpcValue v;
  if (!pnh.getParam(name, v)) return {};
  if (v.getType() != XmlRpc::XmlRpcValue::TypeInt) return typeError(pnh, name, "an integer");
  *out = static_cast<int>(v);
  return {};
}

std::string readParam(const ros::NodeHandle& pnh, const std::string& name, double* out) {
  XmlRpc::XmlRpcValue v;
  if (!pnh.getParam(name, v)) return {};
  if (v.getType() == XmlRpc::XmlRpcValue::TypeInt) {
    *out = static_cast<int>(v);
  } else if (v.getType() == XmlRpc::XmlRpcValue::TypeDouble) {
    *out = static_cast<double>(v);
  } else {
    return typeError(pnh, name, "a number");
  }
  return {};
}

std::string readParam(const ros::NodeHandle& pnh, const std::string& name, bool* out) {
  XmlRpc::XmlRpcValue v;
  if (!pnh.getParam(name, v)) return {};
  if (v.getType() != XmlRpc::XmlRpcValue::TypeBoolean) return typeError(pnh, name, "a boolean");
  *out = static_cast<bool>(v);
  return {};
}

std::string readParam(const ros::NodeHandle& pnh, const std::string& name, std::string* out) {
  XmlRpc::XmlRpcValue v;
  if (!pnh.getParam(name, v)) return {};
  if (v.getType() != XmlRpc::XmlRpcValue::TypeString) return typeError(pnh, name, "a string");
  *out = static_cast<std::string>(v);
  return {};
}

template <typename T>
std::string readBoth(const ros::NodeHandle& pnh, const std::string& name, T* out) {
  std::string e = readParam(pnh, "ros/" + name, out);
  if (!e.empty()) return e;
  return readParam(pnh, name, out);
}

}  // namespace

std::string RosParams::validate() const {
  // The scheduler's settings (backlog, stamp order, unpaired, silence) are checked by its own
  // params struct, with the same names and ranges.
  const std::string scheduler_error = scheduler().validate();
  if (!scheduler_error.empty()) return scheduler_error;
  std::ostringstream m;
  if (queue_size < 1 || queue_size > 100) {
    m << "queue_size: must be in [1, 100], got " << queue_size;
  } else if (!(sync_tolerance_s > 0.0 && sync_tolerance_s <= 1.0)) {
    m << "sync_tolerance_s: must be in (0, 1] s, got " << sync_tolerance_s;
  } else if (image_transport.empty()) {
    m << "image_transport: must not be empty (e.g. raw, compressed)";
  } else if (!(tf_timeout_s >= 0.0 && tf_timeout_s <= 10.0)) {
    m << "tf_timeout_s: must be in [0, 10] s, got " << tf_timeout_s;
  } else if (!(diagnostics_period_s >= 0.05 && diagnostics_period_s <= 60.0)) {
    m << "diagnostics_period_s: must be in [0.05, 60] s, got " << diagnostics_period_s;
  } else if (!(camera_info_wait_s >= 0.0 && camera_info_wait_s <= 10.0)) {
    m << "camera_info_wait_s: must be in [0, 10] s, got " << camera_info_wait_s;
  } else if (!(subpixel_delta_d > 0.0 && subpixel_delta_d <= 1.0)) {
    m << "subpixel_delta_d: must be in (0, 1] px, got " << subpixel_delta_d;
  } else if (freeze_frames < 0 || freeze_frames > 1000) {
    m << "freeze_frames: must be in [0, 1000] (0 = off), got " << freeze_frames;
  } else if (step_check_period_frames < 0 || step_check_period_frames > 100000) {
    m << "step_check_period_frames: must be in [0, 100000] (0 = off), got "
      << step_check_period_frames;
  } else if (right_frame_offset < -5 || right_frame_offset > 5) {
    m << "right_frame_offset: must be in [-5, 5] frames (0 = off), got " << right_frame_offset;
  }
  return m.str();
}

FrameSchedulerParams RosParams::scheduler() const {
  FrameSchedulerParams p;
  p.backlog_pairs = backlog_pairs;
  p.backlog_max_age_s = backlog_max_age_s;
  p.restart_jump_back_s = restart_jump_back_s;
  p.unpaired_timeout_s = unpaired_timeout_s;
  p.no_input_warn_s = no_input_warn_s;
  return p;
}

std::string loadPipelineParamsFromRos(const ros::NodeHandle& pnh, PipelineParams& params) {
  PipelineParams p = params;
  std::string config_file;
  std::string e = readParam(pnh, "config_file", &config_file);
  if (!e.empty()) return e;
  if (!config_file.empty()) {
    e = loadPipelineParams(config_file, p);
    if (!e.empty()) return "parameter " + pnh.resolveName("config_file") + ": " + e;
  }
  for (const std::string& section : pipelineParamSections()) {
    XmlRpc::XmlRpcValue tree;
    if (!pnh.getParam(section, tree)) continue;
    if (tree.getType() != XmlRpc::XmlRpcValue::TypeStruct) {
      return "parameter " + pnh.resolveName(section) + ": expected a map of " + section +
             " parameters";
    }
    for (auto it = tree.begin(); it != tree.end(); ++it) {
      std::string text;
      std::string why;
      const std::string ros_name = pnh.resolveName(section + "/" + it->first);
      if (!scalarToText(it->second, &text, &why)) return "parameter " + ros_name + ": " + why;
      why = setPipelineParam(p, section + "." + it->first, text);
      if (!why.empty()) return "parameter " + ros_name + ": " + why;
    }
  }
  params = p;
  return {};
}

namespace {

// Every RosParams field with its parameter name, one list for reading and for rosParamNames().
template <class F>
void forEachRosParam(RosParams& p, F&& f) {
  f("queue_size", &p.queue_size);
  f("backlog_pairs", &p.backlog_pairs);
  f("backlog_max_age_s", &p.backlog_max_age_s);
  f("approximate_sync", &p.approximate_sync);
  f("sync_tolerance_s", &p.sync_tolerance_s);
  f("image_transport", &p.image_transport);
  f("target_frame", &p.target_frame);
  f("tf_timeout_s", &p.tf_timeout_s);
  f("frame_id", &p.frame_id);
  f("diagnostics_period_s", &p.diagnostics_period_s);
  f("unpaired_timeout_s", &p.unpaired_timeout_s);
  f("camera_info_wait_s", &p.camera_info_wait_s);
  f("restart_jump_back_s", &p.restart_jump_back_s);
  f("subpixel_delta_d", &p.subpixel_delta_d);
  f("no_input_warn_s", &p.no_input_warn_s);
  f("freeze_frames", &p.freeze_frames);
  f("step_check_period_frames", &p.step_check_period_frames);
  f("right_frame_offset", &p.right_frame_offset);
  f("preset", &p.preset);
}

}  // namespace

std::string loadRosParams(const ros::NodeHandle& pnh, RosParams& params) {
  RosParams p = params;
  std::string e;
  forEachRosParam(p, [&](const char* name, auto* field) {
    if (e.empty()) e = readBoth(pnh, name, field);
  });
  if (!e.empty()) return e;
  params = p;
  return {};
}

std::vector<std::string> rosParamNames() {
  RosParams p;
  std::vector<std::string> names;
  forEachRosParam(p, [&](const char* name, auto*) { names.emplace_back(name); });
  return names;
}

void storePipelineParamsToRos(const ros::NodeHandle& pnh, const PipelineParams& params,
                              const PipelineParams* previous) {
  std::vector<ParamInfo> before;
  if (previous) before = listPipelineParams(*previous);
  const std::vector<ParamInfo> now = listPipelineParams(params);
  for (size_t i = 0; i < now.size(); ++i) {
    const ParamInfo& info = now[i];
    // listPipelineParams() lists the keys in a fixed order, so the same index is the same key.
    if (previous && i < before.size() && before[i].key == info.key && before[i].value == info.value) {
      continue;
    }
    const std::string name = info.section + "/" + info.field;
    switch (info.type) {
      case ParamType::kBool:
        pnh.setParam(name, info.value == "true");
        break;
      case ParamType::kInt:
        pnh.setParam(name, std::stoi(info.value));
        break;
      case ParamType::kDouble:
        pnh.setParam(name, std::stod(info.value));
        break;
      case ParamType::kString:
        pnh.setParam(name, info.value);
        break;
    }
  }
}

}  // namespace endo_stereo
