// Uncalibrated rectification (homography and polar); implementation follows.
#include "endo_stereo/core/rectification.hpp"
