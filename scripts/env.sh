# Sourced by the scripts: ROS from Debian under /usr, /usr/bin/python3 first (pyenv's python3 lacks
# the ROS modules, ../shared/PLATFORM.md), and the catkin workspace WS (default: ./.ws, git-ignored; hidden because roslib skips dot-folders when it looks up launch and test files, so it never follows WS/src/endo_stereo back into the repository).
ES_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export WS="${WS:-$ES_ROOT/.ws}"
export PATH="/usr/bin:/usr/lib/nodelet:$PATH"
export ROS_PYTHON_VERSION=3
export PYTHONNOUSERSITE=1
export ROS_LOG_DIR="${ROS_LOG_DIR:-$WS/log}"
es_source_ws() {
  if [ -f "$WS/devel/setup.bash" ]; then
    # shellcheck disable=SC1091
    set +u; source "$WS/devel/setup.bash"; set -u 2>/dev/null || true
  fi
}
