/**
 * @file reconstruction_nodelet.hpp
 * @brief The nodelet `endo_stereo/reconstruction` (exported in nodelet_plugins.xml): reads the
 * parameters, builds a Reconstruction (reconstruction.hpp: topics, behaviour) and serves
 * dynamic_reconfigure (config/EndoStereo.cfg).
 *
 * Parameters (private): the pipeline keys `~section/field` and `~config_file`, the nodelet's
 * own settings (ros_params.hpp: `~queue_size`, `~approximate_sync`, `~sync_tolerance_s`,
 * `~image_transport`, `~target_frame`, `~tf_timeout_s`, `~no_input_warn_s`, `~preset`, ...), and
 * stereo_image_proc's names (stereo_image_proc_params.hpp: `~min_disparity` and
 * `~disparity_range` mapped, the others named in a warning, once). Once started it logs one line
 * with the input topics, rectify mode, synchronisation, disparity range, preset and outputs.
 *
 * A reconfigure request builds a whole new PipelineParams from the parameters in use, validates
 * it and hands it to Reconstruction, which swaps it in between two frames; an invalid request is
 * refused with a message naming the field and the values in use are reported back. An accepted
 * request is written back to the parameter server (the changed `~section/field` values, and
 * `~min_disparity` / `~disparity_range` where they are set), so `rosparam get` shows the values
 * in use.
 *
 * Thread safety: onInit() runs once; the reconfigure callback is serialised by the server.
 */
#pragma once

#include <memory>
#include <mutex>

#include <dynamic_reconfigure/server.h>
#include <endo_stereo/EndoStereoConfig.h>
#include <nodelet/nodelet.h>

#include "endo_stereo/ros/reconstruction.hpp"

namespace endo_stereo {

class ReconstructionNodelet : public nodelet::Nodelet {
 public:
  ReconstructionNodelet() = default;
  ~ReconstructionNodelet() override;

 private:
  void onInit() override;
  void reconfigureCb(EndoStereoConfig& config, uint32_t level);

  std::unique_ptr<Reconstruction> reconstruction_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<EndoStereoConfig>> reconfigure_server_;
};

}  // namespace endo_stereo
