#include "endo_stereo/core/matcher.hpp"
