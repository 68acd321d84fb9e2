/**
 * @file view_offset.hpp
 * @brief Re-pairs the views of a stereo stream whose right view is out of step by a constant
 * number of frames (two capture cards that pair left frame t with right frame t - k).
 *
 * With offset k > 0 the right image taken together with left image t arrives k pairs later, so
 * the left image of pair i is matched with the right image of pair i + k (the left images wait);
 * with k < 0 the right image of pair i is matched with the left image of pair i + |k| (the right
 * images wait). The offset is the one the out-of-step check reports (frame_offset_detector.hpp:
 * "left frame t matches right frame t + k best"). Until |k| pairs have been seen (at the start,
 * and after the stamps go back, a looping bag) nothing comes out: those pairs are held.
 *
 * ROS-free and not thread-safe (the caller serialises push()). @p View is whatever travels with
 * one view of a pair (an image and its camera_info, for instance).
 */
#pragma once

#include <cstdlib>
#include <deque>

namespace endo_stereo {

template <typename View>
class ViewOffset {
 public:
  /// @param offset right frame offset k in frames (0 = pairs pass unchanged).
  explicit ViewOffset(int offset = 0) : offset_(offset) {}

  int offset() const { return offset_; }

  /// The next pair of the stream (stamps increasing). @return true when @p left and @p right now
  /// hold the views to match (their stamps are those of the views, unchanged), false when the
  /// pair is held (its early view kept for a later pair, nothing to match now).
  bool push(double stamp_s, View& left, View& right) {
    if (offset_ == 0) return true;
    if (!held_.empty() && !(stamp_s > last_stamp_s_)) held_.clear();  // time went back
    last_stamp_s_ = stamp_s;
    View& waiting = offset_ > 0 ? left : right;  // the view whose partner arrives later
    held_.push_back(waiting);
    if (static_cast<int>(held_.size()) <= std::abs(offset_)) return false;
    waiting = held_.front();
    held_.pop_front();
    return true;
  }

  /// Forget the held views (a new stream).
  void clear() { held_.clear(); }

 private:
  int offset_ = 0;
  double last_stamp_s_ = 0.0;
  std::deque<View> held_;
};

}  // namespace endo_stereo
